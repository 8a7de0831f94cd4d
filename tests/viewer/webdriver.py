"""A small W3C WebDriver client for Debian's chromium through chromedriver: just what the viewer tests use.

Why not Selenium or Playwright: the W3C protocol is plain JSON over HTTP and the tests need a dozen
commands, so httpx (already a dependency) is enough, and nothing downloads a browser of its own (which
this machine's closed network refuses). Chromium runs headless with the flags this machine needs:
no sandbox (root), no GPU, and no background networking, which the closed network would refuse noisily.
"""

from __future__ import annotations

import base64
import shutil
import subprocess
import tempfile
import time
from pathlib import Path
from typing import Any

import httpx

from tests.service.server import free_port

CHROMIUM_FLAGS = [
    "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
    "--disable-background-networking", "--disable-component-update", "--disable-sync",
    "--disable-dev-shm-usage", "--hide-scrollbars", "--mute-audio",
]
ELEMENT = "element-6066-11e4-a52e-4f735466cecf"  # the W3C key of an element reference


def find_browser() -> tuple[str, str] | str:
    """``(chromium, chromedriver)`` paths, or the reason they are not usable."""
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    driver = shutil.which("chromedriver")
    if not chromium or not driver:
        missing = [n for n, p in (("chromium", chromium), ("chromedriver", driver)) if not p]
        return (f"{' and '.join(missing)} not found: install Debian's chromium and chromium-driver "
                "(apt-get install chromium chromium-driver; .ci/run does this)")
    return chromium, driver


class WebDriverError(RuntimeError):
    pass


class Browser:
    """One headless chromium session; close it with :meth:`quit`."""

    def __init__(self, chromium: str, chromedriver: str, size: tuple[int, int] = (1280, 800),
                 log_dir: Path | None = None) -> None:
        self.profile = tempfile.mkdtemp(prefix="rsmt-chromium-")  # a fresh, empty profile every time
        self.port = free_port()
        log = (log_dir or Path(self.profile)) / "chromedriver.log"
        self.driver = subprocess.Popen([chromedriver, f"--port={self.port}", f"--log-path={log}"],
                                       stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        self.http = httpx.Client(base_url=f"http://127.0.0.1:{self.port}", timeout=60.0)
        deadline = time.monotonic() + 20
        while True:
            try:
                if self.http.get("/status").json()["value"]["ready"]:
                    break
            except (httpx.HTTPError, KeyError, ValueError):
                pass
            if time.monotonic() > deadline or self.driver.poll() is not None:
                self._stop_driver()
                raise WebDriverError(f"chromedriver did not start (log: {log})")
            time.sleep(0.1)
        args = [*CHROMIUM_FLAGS, f"--user-data-dir={self.profile}", f"--window-size={size[0]},{size[1]}"]
        caps = {"capabilities": {"alwaysMatch": {"browserName": "chrome",
                                                 "goog:chromeOptions": {"binary": chromium, "args": args}}}}
        try:
            self.session = self._call("POST", "/session", caps)["sessionId"]
        except Exception:
            self._stop_driver()
            raise

    # ------------------------------------------------------------------ protocol
    def _call(self, method: str, path: str, body: dict | None = None) -> Any:
        res = self.http.request(method, path, json=body if body is not None else ({} if method == "POST" else None))
        data = res.json()
        value = data.get("value")
        if res.status_code >= 400:
            err = value if isinstance(value, dict) else {}
            raise WebDriverError(f"{method} {path}: {err.get('error', res.status_code)}: {str(err.get('message', ''))[:500]}")
        return value

    def cmd(self, method: str, path: str, body: dict | None = None) -> Any:
        return self._call(method, f"/session/{self.session}{path}", body)

    # ------------------------------------------------------------------ commands
    def get(self, url: str) -> None:
        self.cmd("POST", "/url", {"url": url})

    def execute(self, script: str, *args: Any) -> Any:
        """Run ``script`` as a function body (``return ...``) in the page."""
        return self.cmd("POST", "/execute/sync", {"script": script, "args": list(args)})

    def execute_async(self, script: str, *args: Any) -> Any:
        """Run ``script``; it ends by calling ``arguments[arguments.length - 1](value)``."""
        return self.cmd("POST", "/execute/async", {"script": script, "args": list(args)})

    def wait_for(self, expression: str, timeout_s: float = 30.0, what: str | None = None) -> Any:
        """Poll a JS expression until it is truthy; return its value."""
        deadline = time.monotonic() + timeout_s
        while True:
            value = self.execute(f"try {{ return ({expression}); }} catch (e) {{ return null; }}")
            if value:
                return value
            if time.monotonic() > deadline:
                errors = self.execute("return window.rsmtViewer && window.rsmtViewer.errors || null")
                status = self.execute("const s = document.getElementById('status'); return s ? s.textContent : null")
                raise TimeoutError(f"{what or expression} not true within {timeout_s} s; status line: {status!r}; "
                                   f"viewer errors: {errors!r}")
            time.sleep(0.1)

    def find(self, css: str) -> str:
        return self.cmd("POST", "/element", {"using": "css selector", "value": css})[ELEMENT]

    def click(self, css: str) -> None:
        self.cmd("POST", f"/element/{self.find(css)}/click")

    def send_keys(self, css: str, text: str) -> None:
        """Type into an element; for ``<input type=file>`` the text is the path of the file to choose."""
        self.cmd("POST", f"/element/{self.find(css)}/value", {"text": text})

    def click_at(self, css: str, x: float, y: float) -> None:
        """A real mouse click (pointer down and up) at CSS pixel (x, y) from the element's top-left corner."""
        el = self.find(css)
        rect = self.cmd("GET", f"/element/{el}/rect")
        # Pointer origins are the element's centre; offsets must be integers.
        ox, oy = round(x - rect["width"] / 2), round(y - rect["height"] / 2)
        steps = [{"type": "pointerMove", "duration": 0, "origin": {ELEMENT: el}, "x": ox, "y": oy},
                 {"type": "pointerDown", "button": 0}, {"type": "pointerUp", "button": 0}]
        self.cmd("POST", "/actions", {"actions": [{"type": "pointer", "id": "mouse", "parameters": {"pointerType": "mouse"},
                                                   "actions": steps}]})
        self.cmd("DELETE", "/actions")

    def drag(self, css: str, start: tuple[float, float], end: tuple[float, float], steps: int = 5) -> None:
        """Press at ``start``, move to ``end`` in a few steps, release (CSS pixels from the element's corner)."""
        el = self.find(css)
        rect = self.cmd("GET", f"/element/{el}/rect")

        def at(x: float, y: float) -> dict:
            return {"type": "pointerMove", "duration": 20, "origin": {ELEMENT: el},
                    "x": round(x - rect["width"] / 2), "y": round(y - rect["height"] / 2)}

        moves = [at(start[0] + (end[0] - start[0]) * k / steps, start[1] + (end[1] - start[1]) * k / steps)
                 for k in range(1, steps + 1)]
        self.cmd("POST", "/actions", {"actions": [{"type": "pointer", "id": "mouse", "parameters": {"pointerType": "mouse"},
                                                   "actions": [at(*start), {"type": "pointerDown", "button": 0}, *moves,
                                                               {"type": "pointerUp", "button": 0}]}]})
        self.cmd("DELETE", "/actions")

    def scroll(self, css: str, delta_y: int) -> None:
        """Turn the mouse wheel over the element's centre."""
        el = self.find(css)
        self.cmd("POST", "/actions", {"actions": [{"type": "wheel", "id": "wheel", "actions": [
            {"type": "scroll", "origin": {ELEMENT: el}, "x": 0, "y": 0, "deltaX": 0, "deltaY": delta_y, "duration": 0}]}]})
        self.cmd("DELETE", "/actions")

    def screenshot(self, css: str | None = None) -> bytes:
        """PNG of the viewport, or of one element."""
        path = f"/element/{self.find(css)}/screenshot" if css else "/screenshot"
        return base64.b64decode(self.cmd("GET", path))

    def quit(self) -> None:
        try:
            self.cmd("DELETE", "")  # closes chromium; the driver is stopped below either way
        except (httpx.HTTPError, WebDriverError, ValueError):
            pass
        self._stop_driver()
        shutil.rmtree(self.profile, ignore_errors=True)

    def _stop_driver(self) -> None:
        self.http.close()
        if self.driver.poll() is None:
            self.driver.terminate()
            try:
                self.driver.wait(10)
            except subprocess.TimeoutExpired:
                self.driver.kill()


def local_requests_only(browser: Browser, server: Any) -> list[str]:
    """The resources the open page asked for (its resource timing entries, which include requests a
    Content-Security-Policy blocked), asserting that none went anywhere but ``server``; and that no image on
    it is broken. Returns their URLs."""
    entries = browser.execute("return performance.getEntriesByType('resource').map(e => e.name)")
    outside = [name for name in entries if not name.startswith(server.url + "/") and not name.startswith("data:")]
    assert outside == [], outside
    broken = browser.execute("return [...document.images].filter(i => !(i.complete && i.naturalWidth > 0)).map(i => i.src)")
    assert broken == [], broken
    return entries
