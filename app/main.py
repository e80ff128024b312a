"""The FastAPI application factory."""

from __future__ import annotations

from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path

from fastapi import FastAPI
from fastapi.middleware.gzip import GZipMiddleware
from fastapi.staticfiles import StaticFiles
from sqlalchemy import Engine
from starlette.routing import Match, Mount
from starlette.types import Scope

from app import __version__
from app.config import Settings, get_settings
from app.db import make_engine, make_sessionmaker
from app.errors import install_error_handlers
from app.jobs.background import start_background_jobs
from app.jobs.celery_app import CeleryDispatch
from app.jobs.host import JobHost, start_job_host
from app.jobs.kinds import load_kinds
from app.limits import BodyLimitMiddleware
from app.log import configure_logging, install_request_logging
from app.openapi import install_openapi
from app.routers import (
    aircraft,
    assets,
    design_evaluation,
    designs,
    engine_models,
    engine_types,
    engines,
    events,
    fleet_status,
    health,
    installations,
    keys,
    maintenance,
    me,
    notifications,
    reports,
    stream_estimates,
    streams,
    trends,
    uploads,
)
from app.routers import jobs as jobs_router
from app.services import fresh_records
from app.services.jobs.dispatch import Dispatcher, NoDispatch

STATIC_DIR = Path(__file__).resolve().parent.parent / "static"


class DashboardMount(Mount):
    """The dashboard's files, never under /api/: a method an API route does not take is then
    the router's 405 with the route's own Allow header, not the file server's GET, HEAD."""

    def matches(self, scope: Scope) -> tuple[Match, Scope]:
        if scope["type"] == "http" and scope["path"].startswith("/api/"):
            return Match.NONE, {}
        return super().matches(scope)


def create_app(
    settings: Settings | None = None,
    engine: Engine | None = None,
    *,
    background_jobs: bool = False,
    job_host: JobHost | None = None,
) -> FastAPI:
    """Build the application; ``engine`` lets tests hand in their own database.

    ``background_jobs`` starts the embedded job runner and scheduler with the app when
    ``settings.job_runner`` is ``inprocess`` (the embedded default; ``fleethealth serve``): in a
    child process (``app.jobs.host``, ``settings.job_host`` = ``process``, the default) or in
    threads of this process (``thread``). ``job_host``: the child process, started already
    (``fleethealth serve`` starts it first thing, so that both start up at once).
    Without it queued jobs wait for a runner (tests run them with ``run_pending``).
    """
    settings = settings or get_settings()
    configure_logging(settings.log_level, settings.log_json)
    jobs_in_child = background_jobs and settings.job_host == "process"
    engine = engine or make_engine(settings.resolved_database_url)

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        background, host = None, None
        if background_jobs and settings.job_runner == "inprocess" and jobs_in_child:
            host = job_host or start_job_host(settings)
            host.begin()
            app.state.job_dispatcher = host
        elif background_jobs and settings.job_runner == "inprocess":
            background = start_background_jobs(
                app.state.sessionmaker,
                app.state.job_registry,
                heartbeat_seconds=settings.job_heartbeat_seconds,
                stale_after=settings.job_stale_after,
            )
            app.state.job_dispatcher = background.runner
        yield
        if background is not None:
            background.stop()
        if host is not None:
            host.stop()
        engine.dispose()

    app = FastAPI(
        title="fleethealth",
        version=__version__,
        summary="Aircraft engine fleet health trending",
        lifespan=lifespan,
        responses={503: {
            "description": "The database is unavailable (down, restarting or busy): nothing was "
            "stored; retry after the Retry-After header's seconds (uploads safely, with the "
            "same Idempotency-Key).",
            "headers": {"Retry-After": {"schema": {"type": "integer"},
                                        "description": "seconds to wait before retrying"}},
        }},
    )
    app.state.settings = settings
    app.state.engine = engine
    app.state.sessionmaker = make_sessionmaker(engine)
    app.state.job_registry = load_kinds()
    dispatcher: Dispatcher = CeleryDispatch() if settings.job_runner == "celery" else NoDispatch()
    # Uploads keep their records for the estimation job where it runs: in memory here, or in
    # the spool of this server's job host.
    spooled = jobs_in_child and settings.job_runner == "inprocess"
    fresh_records.configure(
        enabled=settings.job_runner != "celery" and (spooled or not jobs_in_child),
        spool=fresh_records.spool_directory(settings.data_dir) if spooled else None,
        empty=spooled,
    )
    app.state.job_dispatcher = dispatcher

    # Not "404.html": StaticFiles(html=True) would send that for unknown API paths too.
    install_error_handlers(app, not_found_page=STATIC_DIR / "not-found.html")
    install_request_logging(app)
    app.add_middleware(BodyLimitMiddleware, max_bytes=settings.max_body_bytes)
    # Pages, scripts and JSON trends compressed for browsers that accept gzip (plotly.js comes
    # compressed already, so the middleware leaves it as it is). Level 1: an engine's trend
    # (790 kB of JSON) compresses to 34 % in 5 ms; level 6 gets 29 % in 30 ms, a cost every
    # page load pays, for 45 kB fewer (4 ms on a 100 Mbit/s link).
    app.add_middleware(GZipMiddleware, minimum_size=1024, compresslevel=1)

    app.include_router(health.router)
    app.include_router(me.router)
    app.include_router(trends.router)
    app.include_router(fleet_status.router)
    app.include_router(reports.router)
    app.include_router(events.router)
    app.include_router(aircraft.router)
    app.include_router(designs.router)
    app.include_router(design_evaluation.router)
    app.include_router(engine_models.router)
    app.include_router(engine_types.router)
    app.include_router(engines.router)
    app.include_router(installations.router)
    app.include_router(keys.router)
    app.include_router(notifications.router)
    app.include_router(maintenance.router)
    app.include_router(uploads.router)
    app.include_router(streams.router)
    app.include_router(stream_estimates.router)
    app.include_router(jobs_router.router)
    app.include_router(assets.router)
    install_openapi(app)
    app.router.routes.append(
        DashboardMount("/", app=StaticFiles(directory=STATIC_DIR, html=True), name="static")
    )
    return app
