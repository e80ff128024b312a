"""fleethealth web service: ingest, estimation pipeline, trends, events and dashboards."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("fleethealth")
except PackageNotFoundError:  # running from a source tree that is not installed
    __version__ = "0.0.0"
