"""``/docs`` and ``/redoc`` work offline (their scripts come from the service, not a CDN), and ``GET /`` leads
to the viewer. Over HTTP, then in headless chromium against the real server on 127.0.0.1."""

from __future__ import annotations

import re

import httpx
import pytest

from tests.viewer.webdriver import local_requests_only

OPERATIONS = ("/v1/transition", "/v1/styles", "/v1/health/ready")


def test_the_root_redirects_to_the_viewer(viewer_server) -> None:
    r = httpx.get(viewer_server.url + "/")
    assert r.status_code == 307 and r.headers["location"] == "/viewer/"
    page = httpx.get(viewer_server.url + "/", follow_redirects=True)
    assert page.status_code == 200 and str(page.url) == viewer_server.url + "/viewer/"
    assert 'src="js/main.js"' in page.text


@pytest.mark.parametrize("path", ["/docs", "/redoc"])
def test_docs_pages_load_only_local_files(viewer_server, path: str) -> None:
    page = httpx.get(viewer_server.url + path)
    assert page.status_code == 200 and page.headers["content-type"].startswith("text/html")
    assert "default-src 'self'" in page.headers["content-security-policy"]  # nothing from outside, even if a script asks
    links = re.findall(r"""(?:src|href)\s*=\s*["']([^"']+)["']""", page.text) + re.findall(r"""url:\s*'([^']+)'""", page.text)
    assert links, page.text
    assert not re.search(r"https?://", page.text), "the page names an outside address"
    for link in links:
        assert link.startswith("/"), link
        r = httpx.get(viewer_server.url + link)
        assert r.status_code == 200 and len(r.content) > 200, (link, r.status_code)
    redoc = httpx.get(viewer_server.url + "/docs/redoc.js")
    assert redoc.status_code == 200 and "Redoc" in redoc.text and "cdn.redoc.ly" not in redoc.text  # its menu's logo


def test_the_service_has_an_icon(viewer_server) -> None:
    icon = httpx.get(viewer_server.url + "/favicon.ico")
    assert icon.status_code == 200 and icon.headers["content-type"] == "image/svg+xml" and b"<svg" in icon.content


def _loaded_from(browser, server) -> list[str]:
    """The resources the page asked for, every one from the server: not even a request that the page's
    Content-Security-Policy would block (it still leaves an entry here, with nothing transferred)."""
    return local_requests_only(browser, server)


@pytest.mark.slow
def test_swagger_ui_renders_the_operations(browser, viewer_server) -> None:
    browser.get(viewer_server.url + "/docs")
    browser.wait_for("document.querySelectorAll('.opblock').length > 10", 60, "Swagger UI to list the operations")
    paths = browser.execute("return [...document.querySelectorAll('.opblock-summary-path')].map(e => e.textContent)")
    for op in OPERATIONS:
        assert any(p.replace("\u200b", "") == op for p in paths), (op, paths)
    loaded = _loaded_from(browser, viewer_server)
    assert any(u.endswith("/docs/static/swagger-ui-bundle.js") for u in loaded), loaded
    assert any(u.endswith("/docs/static/swagger-ui.css") for u in loaded), loaded


@pytest.mark.slow
def test_redoc_renders_the_operations(browser, viewer_server) -> None:
    browser.get(viewer_server.url + "/redoc")
    browser.wait_for("document.querySelectorAll('[data-section-id^=\"operation/\"]').length > 10", 60,
                     "ReDoc to list the operations")
    loaded = _loaded_from(browser, viewer_server)
    assert any(u.endswith("/docs/redoc.js") for u in loaded), loaded  # ReDoc without its CDN logo
