"""Third-party browser assets served from installed Python packages (no CDN).

plotly.js comes from the ``plotly`` package's own bundle, so the dashboard draws with the
version that is installed next to the service. The URL carries no version, so browsers
revalidate daily (ETag / Last-Modified answer 304 when nothing changed).
"""

from __future__ import annotations

from functools import lru_cache
from importlib.resources import files
from pathlib import Path

from fastapi import APIRouter, Request, Response
from fastapi.responses import FileResponse

from app.errors import NotFound

router = APIRouter(tags=["assets"], include_in_schema=False)

CACHE_CONTROL = "public, max-age=86400"


@lru_cache(maxsize=1)
def plotly_bundle() -> Path:
    """Path of ``plotly.min.js`` inside the installed plotly package."""
    return Path(str(files("plotly") / "package_data" / "plotly.min.js"))


@router.get("/vendor/plotly.min.js", response_class=FileResponse)
def plotly_js(request: Request) -> Response:
    path = plotly_bundle()
    if not path.is_file():
        raise NotFound("plotly.js is not installed (the plotly package has no package_data)")
    stat = path.stat()
    etag = f'"plotly-{stat.st_mtime_ns:x}-{stat.st_size:x}"'
    headers = {"Cache-Control": CACHE_CONTROL, "ETag": etag}
    # A revalidation with the current ETag gets 304 rather than the 4.8 MB bundle again.
    if etag in request.headers.get("if-none-match", ""):
        return Response(status_code=304, headers=headers)
    return FileResponse(path, media_type="text/javascript", headers=headers)
