"""The demo operator of the embedded default: created once, its key kept in the data directory."""

from __future__ import annotations

from pathlib import Path

from sqlalchemy import select
from sqlalchemy.orm import Session

from app.models import Operator
from app.services.tenancy.service import authenticate, create_operator, issue_api_key

DEMO_OPERATOR = "Demo Airline"
KEY_FILE = "demo-api-key.txt"


def ensure_demo_operator(session: Session, data_dir: Path) -> str:
    """Return the demo operator's admin key, creating the operator and key on first start.

    The plain key is kept in ``data_dir`` (a laptop's own data) so later starts print the same key.
    """
    key_path = data_dir / KEY_FILE
    if key_path.exists():
        key = key_path.read_text().strip()
        if authenticate(session, key) is not None:
            return key
    operator = session.scalar(select(Operator).where(Operator.name == DEMO_OPERATOR))
    if operator is None:
        operator = create_operator(session, name=DEMO_OPERATOR)
    _row, key = issue_api_key(session, operator=operator, role="admin", name="demo")
    data_dir.mkdir(parents=True, exist_ok=True)
    key_path.write_text(key + "\n")
    key_path.chmod(0o600)
    return key
