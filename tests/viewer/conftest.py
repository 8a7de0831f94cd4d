"""Fixtures of the viewer tests: a real server on 127.0.0.1 (random-weight bundle on the synthetic rig) and,
for the browser tests, headless chromium driven through chromedriver (skipped with the reason when absent)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from model.data.synthetic import synthetic_skeleton
from model.inference.bundle import Bundle
from tests.service.server import Server
from tests.viewer.webdriver import Browser, find_browser

REPO = Path(__file__).resolve().parents[2]
README_SCREENSHOT = REPO / "docs" / "images" / "viewer.png"
UPDATE_SCREENSHOTS = os.environ.get("RSMT_UPDATE_SCREENSHOTS") == "1"


@pytest.fixture(scope="session")
def viewer_bundle(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return Bundle.create(synthetic_skeleton(), seed=0).save(tmp_path_factory.mktemp("viewer-bundle") / "rsmt")


@pytest.fixture(scope="session")
def viewer_server(viewer_bundle: Path):
    srv = Server(viewer_bundle, env={"RSMT_WARMUP_MAX_BATCH": "2"}).start()
    yield srv
    srv.stop()


@pytest.fixture(scope="session")
def artefacts(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Screenshots of the browser tests (always kept here; the README's copy only on request)."""
    return tmp_path_factory.mktemp("viewer-screenshots")


@pytest.fixture(scope="session")
def browser_paths() -> tuple[str, str]:
    """chromium and chromedriver, or a skip naming what is missing (checked before any server starts)."""
    found = find_browser()
    if isinstance(found, str):
        pytest.skip(found)
    return found


@pytest.fixture(scope="module")
def browser(browser_paths: tuple[str, str], viewer_server: Server, artefacts: Path):
    b = Browser(*browser_paths, size=(1280, 900), log_dir=artefacts)
    yield b
    b.quit()
