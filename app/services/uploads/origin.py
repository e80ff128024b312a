"""Where an upload came from: the file's name, the source and the API key's name.

A file's name comes from a multipart part's file name, or from the ``filename`` query
parameter of a raw body (``POST /api/v1/snapshots/file?filename=day-12.csv``). A path is cut
to its last component; an empty name, one over ``MAX_FILENAME`` characters or one with a
control or format character (a line break, NUL, a bidirectional override) is refused (422)
before anything is read into the history. The source is declared by the client: ``browser``
(the uploads page), ``cli`` (``fleethealth import-cmapss``) or ``api`` (anything else, the
default). The key's name is kept as it was at upload time.
"""

from __future__ import annotations

import unicodedata
from dataclasses import dataclass

from sqlalchemy import select
from sqlalchemy.orm import Session

from app.errors import InvalidInput
from app.models import ApiKey, Upload

MAX_FILENAME = 255
_REFUSED_CATEGORIES = ("Cc", "Cf", "Zl", "Zp")


@dataclass(frozen=True)
class UploadOrigin:
    """An upload's file name (None: not sent) and its declared source."""

    filename: str | None = None
    source: str = "api"


def clean_filename(name: str | None) -> str | None:
    """The file's name without its directories; None when none was sent; InvalidInput (422)
    for a name that cannot be shown safely."""
    if name is None:
        return None
    if any(unicodedata.category(c) in _REFUSED_CATEGORIES for c in name):
        raise InvalidInput(
            "filename: control or format characters are not allowed",
            details=[{"column": "filename", "reason": "control or format character"}],
        )
    base = name.replace("\\", "/").rsplit("/", 1)[-1].strip()
    if not base:
        raise InvalidInput(
            "filename: empty", details=[{"column": "filename", "reason": "empty file name"}]
        )
    if len(base) > MAX_FILENAME:
        raise InvalidInput(
            f"filename: longer than {MAX_FILENAME} characters",
            details=[{"column": "filename", "reason": f"over {MAX_FILENAME} characters"}],
        )
    return base


def stamp(session: Session, upload: Upload, origin: UploadOrigin | None,
          api_key_id: int | None) -> None:
    """Write the origin and the key's current name on a new upload row."""
    origin = origin or UploadOrigin()
    upload.filename = origin.filename
    upload.source = origin.source
    if api_key_id is not None:
        upload.api_key_name = session.scalar(select(ApiKey.name).where(ApiKey.id == api_key_id))
