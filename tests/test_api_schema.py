"""Property-based API conformance: schemathesis over the whole OpenAPI schema.

Every operation is called with a few generated requests (seeded, so a run repeats) by an
authenticated admin of an operator with a small fleet, on SQLite and on PostgreSQL. Every
check runs: no 5xx, every status code and content type documented, every JSON body valid
against its response schema, invalid requests refused with a 4xx.
"""

from __future__ import annotations

import itertools
from typing import Any

import pytest
import schemathesis
from fastapi import FastAPI
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis.errors import Unsatisfiable
from schemathesis.specs.openapi.checks import positive_data_acceptance
from sqlalchemy.orm import Session

from app.models import Operator
from app.services.tenancy import service as tenancy
from tests.support.fleet_fixture import make_fleet

pytestmark = pytest.mark.long(seconds=30)

EXAMPLES = 3
# Valid requests, and requests that break the schema on purpose (each must be a 4xx).
MODES = (schemathesis.GenerationMode.POSITIVE, schemathesis.GenerationMode.NEGATIVE)
# positive_data_acceptance is left out: a schema-valid body may still name an engine that
# does not exist or break a rule across fields (start before end); those are 4xx by design.
CONFIG = schemathesis.Config.from_dict({
    "generation": {"max-examples": 3, "deterministic": True},
    "phases": {"coverage": {"enabled": False}, "stateful": {"enabled": False}},
})


@pytest.fixture
def api_key(session: Session) -> str:
    fleet = make_fleet(session)
    operator = session.get(Operator, fleet.operator_id)
    _row, key = tenancy.issue_api_key(
        session, operator=operator, role="admin", name="schema-test"
    )
    session.commit()
    return key


def _one_line(failure: BaseException) -> str:
    lines = [line.strip() for line in str(failure).splitlines() if line.strip()]
    return " | ".join(lines)[:300]


def _run(operation: Any, mode: Any, api_key: str, failures: list[str]) -> None:
    """Call ``operation`` with a few generated requests; each failed check joins ``failures``."""

    @given(case=operation.as_strategy(generation_mode=mode))
    @settings(max_examples=EXAMPLES, derandomize=True, deadline=None, database=None,
              suppress_health_check=list(HealthCheck), phases=[Phase.explicit, Phase.generate])
    def check(case: schemathesis.Case) -> None:
        try:
            case.call_and_validate(
                headers={"X-API-Key": api_key}, excluded_checks=[positive_data_acceptance]
            )
        except (AssertionError, BaseExceptionGroup) as exc:  # reported together below
            found = exc.exceptions if isinstance(exc, BaseExceptionGroup) else (exc,)
            for failure in found:
                failures.append(f"{operation.label}: {_one_line(failure)}")

    try:
        check()
    except Unsatisfiable:
        # Negative mode on an operation without parameters or body: nothing to break.
        assert mode == schemathesis.GenerationMode.NEGATIVE, operation.label


def test_api_conforms_to_its_schema(app: FastAPI, api_key: str) -> None:
    api = schemathesis.openapi.from_asgi("/openapi.json", app, config=CONFIG)
    failures: list[str] = []
    operations = [result.ok() for result in api.get_all_operations()]
    for operation, mode in itertools.product(operations, MODES):
        _run(operation, mode, api_key, failures)
    assert not failures, f"{len(failures)} failures:\n" + "\n".join(failures)
