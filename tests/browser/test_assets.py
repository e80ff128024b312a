"""plotly.js is served from the installed plotly package, cached, and revalidated with 304."""

from __future__ import annotations

from importlib.resources import files

from fastapi.testclient import TestClient


def test_plotly_bundle_is_the_installed_package_file_with_caching(client: TestClient) -> None:
    response = client.get("/vendor/plotly.min.js")
    assert response.status_code == 200
    assert response.content == (files("plotly") / "package_data" / "plotly.min.js").read_bytes()
    assert response.headers["content-type"].startswith("text/javascript")
    assert "max-age=" in response.headers["cache-control"]
    again = client.get("/vendor/plotly.min.js", headers={"If-None-Match": response.headers["etag"]})
    assert again.status_code == 304 and again.content == b""
    stale = client.get("/vendor/plotly.min.js", headers={"If-None-Match": '"other"'})
    assert stale.status_code == 200


def test_every_page_loads_plotly_from_the_service_not_a_cdn(client: TestClient) -> None:
    for page in ("/", "/engine.html", "/events.html", "/designs.html"):
        html = client.get(page).text
        assert '<script src="/vendor/plotly.min.js"></script>' in html, page
        assert "cdn" not in html.lower() and "https://" not in html, page
