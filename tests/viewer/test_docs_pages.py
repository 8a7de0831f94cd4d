"""``/docs`` and ``/redoc`` work offline (their scripts come from the service, not a CDN), and ``GET /`` leads
to the viewer. Over HTTP, then in headless chromium against the real server on 127.0.0.1."""

from __future__ import annotations

import re

import httpx
import pytest

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
        assert r.status_code == 200 and len(r.content) > 1000, (link, r.status_code)


def _loaded_from(browser, server) -> list[str]:
    """The resources the page loaded: all from the server. ReDoc asks for a logo from its CDN, which the
    page's Content-Security-Policy blocks (an entry with nothing transferred; ReDoc then drops the image)."""
    entries = browser.execute("return performance.getEntriesByType('resource').map(e => [e.name, e.transferSize])")
    outside = [(name, size) for name, size in entries if not name.startswith(server.url + "/")]
    assert all(size == 0 for _, size in outside), outside
    broken = browser.execute("return [...document.images].filter(i => !(i.complete && i.naturalWidth > 0)).map(i => i.src)")
    assert broken == []
    return [name for name, _ in entries if name.startswith(server.url + "/")]


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
    assert any(u.endswith("/docs/static/redoc.standalone.js") for u in loaded), loaded
