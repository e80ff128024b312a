"""Third-party browser assets served from installed Python packages (no CDN).

plotly.js comes from the ``plotly`` package's own bundle, so the dashboard draws with the
version that is installed next to the service. The URL carries no version, so browsers
revalidate daily (ETag / Last-Modified answer 304 when nothing changed). The 4.8 MB bundle is
compressed once per installed version (about 1.4 MB as gzip) and sent so to every browser that
accepts gzip, rather than compressed again on each request.
"""

from __future__ import annotations

import gzip
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


@lru_cache(maxsize=1)
def plotly_gzip(path: Path, version: str) -> bytes:
    """The bundle as gzip, once per installed version (``version``: the file's ETag)."""
    return gzip.compress(path.read_bytes(), compresslevel=9, mtime=0)


def accepts_gzip(request: Request) -> bool:
    codings = request.headers.get("accept-encoding", "").lower().split(",")
    return any(c.split(";")[0].strip() == "gzip" and "q=0" not in c.replace(" ", "")
               for c in codings)


@router.get("/vendor/plotly.min.js", response_class=FileResponse)
def plotly_js(request: Request) -> Response:
    path = plotly_bundle()
    if not path.is_file():
        raise NotFound("plotly.js is not installed (the plotly package has no package_data)")
    stat = path.stat()
    etag = f'"plotly-{stat.st_mtime_ns:x}-{stat.st_size:x}"'
    compressed = accepts_gzip(request)
    # Each encoding is its own representation with its own validator (RFC 9110 8.8.3).
    if compressed:
        etag = etag[:-1] + '-gz"'
    headers = {"Cache-Control": CACHE_CONTROL, "ETag": etag, "Vary": "Accept-Encoding"}
    # A revalidation with the current ETag gets 304 rather than the 4.8 MB bundle again.
    if etag in request.headers.get("if-none-match", ""):
        return Response(status_code=304, headers=headers)
    if compressed:
        return Response(plotly_gzip(path, etag), media_type="text/javascript",
                        headers={**headers, "Content-Encoding": "gzip"})
    return FileResponse(path, media_type="text/javascript", headers=headers)
