"""How the dashboard is served: compressed, with an HTML page for unknown pages and JSON 404s
for the API."""

from __future__ import annotations

import gzip
from importlib.resources import files

from fastapi.testclient import TestClient

PLOTLY = (files("plotly") / "package_data" / "plotly.min.js").read_bytes()


def _raw(client: TestClient, path: str, **headers: str) -> tuple[int, dict[str, str], bytes]:
    """Status, headers and the body as sent (not decoded by the client)."""
    with client.stream("GET", path, headers=headers) as response:
        return response.status_code, dict(response.headers), b"".join(response.iter_raw())


def test_plotly_bundle_is_sent_as_gzip_to_browsers_that_accept_it(client: TestClient) -> None:
    status, headers, body = _raw(client, "/vendor/plotly.min.js", **{"Accept-Encoding": "gzip"})
    assert status == 200
    assert headers["content-encoding"] == "gzip"
    assert "accept-encoding" in headers["vary"].lower()
    assert gzip.decompress(body) == PLOTLY
    assert len(body) < len(PLOTLY) / 2
    # Its own validator: a revalidation of the gzip copy is 304, of the plain copy too.
    again = client.get("/vendor/plotly.min.js", headers={"Accept-Encoding": "gzip",
                                                          "If-None-Match": headers["etag"]})
    assert again.status_code == 304
    status, plain_headers, plain = _raw(client, "/vendor/plotly.min.js",
                                        **{"Accept-Encoding": "identity"})
    assert status == 200 and "content-encoding" not in plain_headers and plain == PLOTLY
    assert plain_headers["etag"] != headers["etag"]


def test_pages_scripts_and_api_answers_are_compressed(client: TestClient) -> None:
    for path in ("/", "/js/engine.js", "/css/app.css", "/openapi.json"):
        status, headers, body = _raw(client, path, **{"Accept-Encoding": "gzip"})
        assert status == 200, path
        assert headers.get("content-encoding") == "gzip", path
        assert gzip.decompress(body) == client.get(path).content, path


def test_unknown_page_is_an_html_page_and_unknown_api_path_json(client: TestClient) -> None:
    page = client.get("/nosuchpage", headers={"Accept": "text/html"})
    assert page.status_code == 404
    assert page.headers["content-type"].startswith("text/html")
    assert "Page not found" in page.text and 'href="/"' in page.text
    assert client.get("/css/nosuch.css").status_code == 404
    api = client.get("/api/v1/nosuch")
    assert api.status_code == 404
    assert api.headers["content-type"] == "application/json"
    assert api.json()["error"]["code"] == "not_found"
    # A missing object of the API keeps its JSON 404 too.
    missing = client.get("/api/v1/engines/999999", headers={"X-API-Key": "fh_wrong"})
    assert missing.headers["content-type"] == "application/json"
