"""The web page at ``/``: served with its assets, outside the OpenAPI document, same-origin only."""

from __future__ import annotations

import re
from collections.abc import Iterator
from html.parser import HTMLParser

import pytest
from fastapi.testclient import TestClient

from backend.settings import Settings
from service.app import create_app
from service.routes.page import STATIC_DIR

ASSETS = {
    "app.js": "text/javascript",
    "app.css": "text/css",
    "favicon.svg": "image/svg+xml",
}


class _Refs(HTMLParser):
    """Every ``src`` and ``href`` in a document."""

    def __init__(self) -> None:
        super().__init__()
        self.refs: list[tuple[str, str, str]] = []

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        for name, value in attrs:
            if name in ("src", "href", "action") and value is not None:
                self.refs.append((tag, name, value))


def _refs(html: str) -> list[tuple[str, str, str]]:
    parser = _Refs()
    parser.feed(html)
    return parser.refs


@pytest.fixture
def client(settings: Settings) -> Iterator[TestClient]:
    with TestClient(create_app(settings)) as c:
        yield c


def test_root_serves_the_page(client: TestClient) -> None:
    response = client.get("/")
    assert response.status_code == 200
    assert response.headers["content-type"] == "text/html; charset=utf-8"
    assert "<title>Eigenscope</title>" in response.text
    assert 'id="upload-form"' in response.text
    csp = response.headers["content-security-policy"]
    assert "default-src 'self'" in csp
    assert "script-src 'self'" in csp
    assert response.headers["x-content-type-options"] == "nosniff"
    assert client.head("/").status_code == 200


@pytest.mark.parametrize(("name", "media_type"), sorted(ASSETS.items()))
def test_static_assets_are_served(client: TestClient, name: str, media_type: str) -> None:
    response = client.get(f"/static/{name}")
    assert response.status_code == 200
    assert response.headers["content-type"].split(";")[0] == media_type
    assert response.content == (STATIC_DIR / name).read_bytes()


def test_every_asset_the_page_references_is_served(client: TestClient) -> None:
    html = client.get("/").text
    local = [value for _tag, _attr, value in _refs(html) if value.startswith("static/")]
    assert {"static/app.js", "static/app.css", "static/favicon.svg"} <= set(local)
    for value in local:
        assert client.get(f"/{value}").status_code == 200, value


def test_each_job_has_a_page_of_its_own(client: TestClient) -> None:
    """``/jobs/{id}`` is the page with its base one level up, so its relative links reach the same files."""
    root = client.get("/")
    job = client.get("/jobs/0123abcd")
    assert job.status_code == 200
    assert job.headers["content-type"].startswith("text/html")
    assert job.headers["content-security-policy"] == root.headers["content-security-policy"]
    assert "base-uri 'self'" in job.headers["content-security-policy"]
    assert '<base href="./">' in root.text
    assert '<base href="../">' in job.text
    assert job.text.replace('<base href="../">', '<base href="./">') == root.text
    assert client.head("/jobs/0123abcd").status_code == 200
    paths = client.get("/openapi.json").json()["paths"]
    assert not any(p.startswith("/jobs") for p in paths)


def test_missing_static_file_is_a_404_not_a_traceback(client: TestClient) -> None:
    assert client.get("/static/nope.js").status_code == 404
    assert client.get("/static/../app.py").status_code == 404


def test_page_routes_are_not_in_the_openapi_document(client: TestClient) -> None:
    paths = client.get("/openapi.json").json()["paths"]
    assert "/" not in paths
    assert not any(p.startswith("/static") for p in paths)


def test_the_page_links_to_the_api_docs(client: TestClient) -> None:
    hrefs = [value for tag, attr, value in _refs(client.get("/").text) if tag == "a" and attr == "href"]
    assert "docs" in hrefs
    assert client.get("/docs").status_code == 200


def test_the_page_loads_nothing_from_another_origin() -> None:
    html = (STATIC_DIR / "index.html").read_text()
    for tag, attr, value in _refs(html):
        if value.startswith("#"):
            continue
        assert not re.match(r"^([a-z][a-z0-9+.-]*:|//)", value, re.IGNORECASE), (tag, attr, value)

    js = (STATIC_DIR / "app.js").read_text()
    # No absolute or protocol-relative URL in a string literal; no dynamic imports or remote workers.
    assert not re.search(r"""["'`]\s*(https?:|wss?:)?//""", js), "app.js must use relative, same-origin URLs"
    assert not re.search(r"https?://", js)
    assert "import(" not in js
    assert "importScripts" not in js

    css = (STATIC_DIR / "app.css").read_text()
    assert "@import" not in css
    assert not re.search(r"url\(\s*['\"]?\s*(https?:)?//", css)
    assert not re.search(r"https?://", css)


def test_docs_are_served_without_a_cdn(tmp_path):
    from fastapi.testclient import TestClient

    from backend.settings import Settings
    from service.app import create_app

    app = create_app(Settings(data_dir=tmp_path))
    with TestClient(app) as client:
        html = client.get("/docs")
        assert html.status_code == 200
        assert "cdn" not in html.text.lower()
        assert "/docs-assets/swagger-ui-bundle.js" in html.text
        js = client.get("/docs-assets/swagger-ui-bundle.js")
        assert js.status_code == 200
        assert len(js.content) > 100_000
