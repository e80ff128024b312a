"""Commands that run the service's components: migrate, serve, worker, beat, operators."""

from __future__ import annotations

import typer

from app.config import get_settings


def register(app: typer.Typer) -> None:
    app.command()(migrate)
    app.command()(downgrade)
    app.command()(serve)
    app.command()(worker)
    app.command()(beat)
    app.command("create-operator")(create_operator)


def migrate(revision: str = typer.Option("head", help="Alembic revision to upgrade to.")) -> None:
    """Upgrade the database to the latest schema (the only way tables are made)."""
    from app.migrate import upgrade

    settings = get_settings()
    upgrade(settings.resolved_database_url, revision)
    typer.echo(f"database at {revision}: {_safe_url(settings.resolved_database_url)}")


def downgrade(
    revision: str = typer.Argument(..., help="Alembic revision to go back to, e.g. base."),
) -> None:
    """Downgrade the database schema."""
    from app.migrate import downgrade as alembic_downgrade

    settings = get_settings()
    alembic_downgrade(settings.resolved_database_url, revision)
    typer.echo(f"database at {revision}")


def serve(
    host: str | None = typer.Option(None, help="Interface to listen on."),
    port: int | None = typer.Option(None, help="Port to listen on."),
    skip_migrate: bool = typer.Option(False, help="Do not run migrations first."),
    demo: bool = typer.Option(True, help="Create the demo operator on first start."),
    jobs: bool = typer.Option(
        True,
        "--jobs/--no-jobs",
        help="Run jobs and schedules in this process (when FLEETHEALTH_JOB_RUNNER=inprocess).",
    ),
) -> None:
    """Migrate, then serve the API and the dashboard with uvicorn."""
    settings = get_settings()
    job_host = None
    if jobs and settings.job_runner == "inprocess" and settings.job_host == "process":
        from app.jobs.host import start_job_host

        job_host = start_job_host(settings)  # first: its start-up overlaps the server's

    import uvicorn

    from app.db import make_engine, make_sessionmaker, transaction
    from app.main import create_app
    from app.migrate import upgrade
    from app.services.demo.operator import ensure_demo_operator

    host = host or settings.host
    port = port or settings.port
    if not skip_migrate:
        upgrade(settings.resolved_database_url)
    engine = make_engine(settings.resolved_database_url)
    key = None
    if demo:
        with transaction(make_sessionmaker(engine)) as session:
            key = ensure_demo_operator(session, settings.data_dir)
        from app.services.demo.fleet import ensure_demo_fleet

        ensure_demo_fleet(make_sessionmaker(engine), echo=typer.echo)
        from app.jobs.demo import queue_demo_evaluations, queue_demo_stream_calibration

        with transaction(make_sessionmaker(engine)) as session:
            if queue_demo_evaluations(session) and jobs:
                typer.echo("demo designs: Monte Carlo evaluations queued (see the jobs page)")
            if queue_demo_stream_calibration(session) is not None and jobs:
                typer.echo("demo design: its stream estimates' calibration queued (see the "
                           "jobs page)")
    base = f"http://{host}:{port}"
    typer.echo(f"fleethealth dashboard: {base}/")
    typer.echo(f"API documentation:     {base}/docs")
    if key:
        typer.echo(f"demo API key:          {key}")
    app = create_app(settings, engine, background_jobs=jobs, job_host=job_host)
    uvicorn.run(app, host=host, port=port, log_level="warning")


def worker(
    concurrency: int = typer.Option(2, help="Worker processes."),
    queue: str = typer.Option("fleethealth", help="Broker queue to take jobs from."),
) -> None:
    """Run a Celery worker (deployment mode; the embedded default runs jobs in-process).

    It runs the same job functions as the in-process runner, claiming each job in the database.
    """
    from app.jobs.celery_tasks import celery

    # Workers coordinate through the jobs table, not through each other: no mingle or gossip.
    celery.worker_main(
        ["worker", "--loglevel=INFO", f"--concurrency={concurrency}", "--queues", queue]
        + ["--without-mingle", "--without-gossip"]
    )


def beat() -> None:
    """Run Celery beat (deployment mode): it sends the tick that submits due job schedules.

    The schedules themselves live in the database (/api/v1/schedules); run one beat only.
    """
    from app.jobs.celery_tasks import celery

    celery.start(["beat", "--loglevel=INFO"])


def create_operator(
    name: str = typer.Argument(..., help="Operator (airline or MRO) name."),
    role: str = typer.Option("admin", help="Role of the first API key: viewer, analyst or admin."),
) -> None:
    """Create an operator and print its first API key (shown once)."""
    from app.db import make_engine, make_sessionmaker, transaction
    from app.services.tenancy import service as tenancy

    settings = get_settings()
    with transaction(make_sessionmaker(make_engine(settings.resolved_database_url))) as session:
        operator = tenancy.create_operator(session, name=name)
        _row, key = tenancy.issue_api_key(session, operator=operator, role=role, name="first key")
    typer.echo(key)


def _safe_url(url: str) -> str:
    from sqlalchemy.engine import make_url

    return make_url(url).render_as_string(hide_password=True)
