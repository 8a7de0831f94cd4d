"""The HTTP and WebSocket examples of docs/service.md (section *Endpoints*) and the README's *Calling it*, run
as written (curl, jq, python) against a real server on the shipped default model, from an empty folder."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from model.inference.bundle import DEFAULT_BUNDLE
from tests.service.server import Server

pytestmark = pytest.mark.slow
REPO = Path(__file__).resolve().parents[2]
DOC_URL = "http://127.0.0.1:8000"


def blocks(path: Path, section: str, language: str) -> list[str]:
    """The fenced ``language`` blocks of the markdown section headed ``section`` (up to the next ``## ``)."""
    text = path.read_text()
    start = text.index(section + "\n")
    stop = text.find("\n## ", start + len(section))
    body = text[start:stop if stop > 0 else None]
    return re.findall(rf"```{language}\n(.*?)```", body, flags=re.S)


@pytest.fixture(scope="module")
def server():
    if not (shutil.which("curl") and shutil.which("jq")):
        pytest.skip("the examples need curl and jq (apt-get install curl jq)")
    srv = Server(DEFAULT_BUNDLE, env={"RSMT_WARMUP_MAX_BATCH": "1", "RSMT_EAGER": "true"}).start(300)
    yield srv
    srv.stop()


def run_bash(script: str, url: str, cwd: Path) -> str:
    assert f"URL={DOC_URL}\n" in script
    done = subprocess.run(["bash", "-euo", "pipefail", "-c", script.replace(f"URL={DOC_URL}", f"URL={url}")],
                          cwd=cwd, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, f"exit {done.returncode}\nstdout:\n{done.stdout[-3000:]}\nstderr:\n{done.stderr[-3000:]}"
    return done.stdout


def test_the_service_docs_endpoint_examples_run(server, tmp_path) -> None:
    (script,) = blocks(REPO / "docs" / "service.md", "## Endpoints", "bash")
    out = run_bash(script, server.url, tmp_path)
    assert '"status":"alive"' in out and '"name":"rsmt-default"' in out
    assert "builtin:elderly\n" in out and "builtin:youthful\n" in out
    assert '"style_id": "builtin:elderly"' in out and '"frames": 40' in out
    assert re.search(r'^"sty_[0-9a-f]{24}"$', out, flags=re.M)  # the registered style, used by id
    assert out.count('"inline"') == 0 and "\n204\n" in out
    assert "Frames: 40\n" in (tmp_path / "transition.bvh").read_text()
    assert '"name": "transition.bvh"' in out  # the viewer's clip reader
    assert "rsmt_frames_generated_total" in (tmp_path / "metrics.txt").read_text()

    # The WebSocket example of the same section, in the same folder (it reads walk.json).
    (python,) = blocks(REPO / "docs" / "service.md", "## Endpoints", "python")
    ws = server.url.replace("http://", "ws://")
    done = subprocess.run([sys.executable, "-c", python.replace("ws://127.0.0.1:8000", ws)], cwd=tmp_path,
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-3000:]
    assert done.stdout.strip() == "40 arrived"


def test_the_readme_calling_it_example_runs(server, tmp_path) -> None:
    script = blocks(REPO / "README.md", "## Calling it", "bash")[0]
    run_bash(script, server.url, tmp_path)
    assert "Frames: 40\n" in (tmp_path / "transition.bvh").read_text()
