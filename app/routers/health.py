"""Liveness and database readiness."""

from __future__ import annotations

from fastapi import APIRouter, Request
from fastapi.responses import JSONResponse
from pydantic import BaseModel
from sqlalchemy.exc import SQLAlchemyError

from app import __version__
from app.db import ping

router = APIRouter(tags=["health"])


class Health(BaseModel):
    status: str
    version: str
    database: str
    backend: str


@router.get("/health", response_model=Health, responses={503: {"model": Health}})
def health(request: Request) -> Health | JSONResponse:
    """200 when the service and its database answer, 503 when the database does not."""
    engine = request.app.state.engine
    backend = engine.dialect.name
    try:
        ping(engine)
    except SQLAlchemyError:
        body = Health(
            status="unavailable", version=__version__, database="unreachable", backend=backend
        )
        return JSONResponse(body.model_dump(), status_code=503)
    return Health(status="ok", version=__version__, database="ok", backend=backend)
