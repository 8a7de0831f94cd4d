"""Every shell and Python example of README.md, docs/service.md and clients/python/README.md, run as written
(curl, jq, python, the ``rsmt`` command) against a real server on 127.0.0.1 on the shipped default model.

Each document's blocks run in order in one empty folder, as a reader would run them (a later block may read the
files an earlier one wrote); only the address changes, ``http://127.0.0.1:8000`` to the test server's. A block
that cannot run in a test is listed in :data:`NOT_RUN` with the reason and where it is tested instead; every
entry there must name exactly one block, so the list cannot go stale silently.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

from tests.service.server import Server

pytestmark = pytest.mark.slow
REPO = Path(__file__).resolve().parents[2]
DOC_URL = "http://127.0.0.1:8000"
DOCS = ("README.md", "docs/service.md", "clients/python/README.md")
SHELL, PYTHON = ("bash", "sh", "shell", "console"), ("python", "py")

# (document, a line of the block) -> why it is not run here.
NOT_RUN: dict[tuple[str, str], str] = {
    ("README.md", "pip install -e ./clients/python -e . && rsmt serve"):
        "installs the project into a new virtual environment, then serves on port 8000 until stopped",
    ("README.md", "pip install -e ./clients/python -e '.[test]' && python -m pytest -q -n 2"):
        "installs into a new virtual environment and runs the whole test suite, this test included",
    ("README.md", 'python -m pytest -q -n 2 -m "not slow"'):
        "the fast test tier: a run of this suite's own unmarked tests, from the repository root",
    ("README.md", "rsmt train recipe default-model"): "trains the default model: about three hours on 2 cores",
    ("README.md", "export RSMT_DATA=$(bash ../shared/data/unpack.sh)"):
        "unpacks the motion data, which lives outside the repository (tests/cli/test_data_commands.py runs "
        "`rsmt data inspect`)",
    ("README.md", 'export RSMT_DATA="$(bash ../shared/data/unpack.sh):$(bash ../shared/data/unpack.sh --dataset-1)"'):
        "unpacks both datasets, which live outside the repository (tests/model/data/test_two_datasets.py reads "
        "them side by side)",
    ("docs/service.md", "rsmt serve --threads 4"):
        "servers on port 8000 and 9000 that run until stopped (tests/cli/test_serve_command.py)",
    ("docs/service.md", "rsmt serve --models /tmp/rsmt-random"): "ends in a server that runs until stopped",
    ("docs/service.md", "rsmt package --model trained/"):
        "needs a trained bundle and style clips of your own (tests/cli/test_package_command.py)",
    ("docs/service.md", "rsmt finetune-style --model model/default_bundle"):
        "needs clips of a new style and trains for minutes (tests/cli/test_finetune_command.py)",
    ("docs/service.md", "docker build -t rsmt ."): "builds and runs the container image (tests/deploy/test_image.py)",
    ("docs/service.md", "redis-server --port 6379 --appendonly yes &"):
        "Redis and two servers on fixed ports in the background (tests/service/test_replicas.py)",
    ("docs/service.md", "rsmt loadtest --spawn --bundle model/default_bundle --characters 64 --seconds 300 --soak"):
        "a five-minute soak (tests/clients/test_loadtest_command.py runs short load tests)",
    ("clients/python/README.md", "pip install ./clients/python"):
        "installs the package (tests/clients/test_standalone_install.py does, in a fresh environment)",
}


@dataclass(frozen=True)
class Block:
    doc: str
    language: str
    text: str
    line: int

    @property
    def shell(self) -> bool:
        return self.language in SHELL


def blocks(doc: str) -> list[Block]:
    """The document's fenced blocks whose info string names a shell or Python (the first word of it)."""
    text = (REPO / doc).read_text()
    found = []
    for m in re.finditer(r"^```([^\n`]*)\n(.*?)^```", text, flags=re.S | re.M):
        language = (m.group(1).split() or [""])[0].lower()
        if language in SHELL + PYTHON:
            found.append(Block(doc, language, m.group(2), text.count("\n", 0, m.start()) + 1))
    return found


def not_run(block: Block) -> str | None:
    reasons = [why for (doc, line), why in NOT_RUN.items() if doc == block.doc and line in block.text]
    assert len(reasons) <= 1, (block.doc, block.line, reasons)
    return reasons[0] if reasons else None


def test_every_entry_of_the_not_run_list_names_exactly_one_block() -> None:
    for (doc, line), why in NOT_RUN.items():
        matching = [b.line for b in blocks(doc) if line in b.text]
        assert len(matching) == 1, (doc, line, matching)
        assert why
    for doc in DOCS:  # and most blocks run
        found = blocks(doc)
        assert sum(not_run(b) is None for b in found) >= 2, doc


@pytest.fixture(scope="module")
def server(request: pytest.FixtureRequest) -> Server:
    if not (shutil.which("curl") and shutil.which("jq")):
        pytest.skip("the examples need curl and jq (apt-get install curl jq)")
    return request.getfixturevalue("default_model_eager_server")  # tests/conftest.py: shared with the viewer's tests


def run(block: Block, server: Server, cwd: Path) -> str:
    """Run one block in ``cwd`` against ``server``; its stdout."""
    ws = server.url.replace("http://", "ws://")
    text = block.text.replace(DOC_URL, server.url).replace(DOC_URL.replace("http://", "ws://"), ws)
    env = {**os.environ, "RSMT_URL": server.url,  # `rsmt client` commands without --url
           "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}"}
    command = ["bash", "-euo", "pipefail", "-c", text] if block.shell else [sys.executable, "-c", text]
    done = subprocess.run(command, cwd=cwd, env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, (f"{block.doc}:{block.line}: exit {done.returncode}\nstdout:\n{done.stdout[-3000:]}\n"
                                  f"stderr:\n{done.stderr[-3000:]}")
    return done.stdout


def run_doc(doc: str, server: Server, folder: Path) -> dict[int, str]:
    """Every block of ``doc`` that is not in :data:`NOT_RUN`, in order, in ``folder``: stdout by first line."""
    return {b.line: run(b, server, folder) for b in blocks(doc) if not_run(b) is None}


def frames_of(path: Path) -> int:
    match = re.search(r"^Frames:\s*(\d+)", path.read_text(), flags=re.M)
    assert match, path
    return int(match.group(1))


def test_the_readme_examples_run(server, tmp_path) -> None:
    outs = run_doc("README.md", server, tmp_path)
    assert len(outs) == 2  # the curl example and the Python one
    assert frames_of(tmp_path / "transition.bvh") == 40  # curl
    assert frames_of(tmp_path / "out.bvh") == 40  # Python, from the model's demo walks
    assert frames_of(tmp_path / "walk.bvh") == 240 and frames_of(tmp_path / "context.bvh") == 60


def test_the_service_docs_examples_run(server, tmp_path) -> None:
    outs = run_doc("docs/service.md", server, tmp_path)
    endpoints, websocket = (outs[b.line] for b in blocks("docs/service.md") if not_run(b) is None)
    assert '"status":"alive"' in endpoints and '"name":"rsmt-default"' in endpoints
    assert "builtin:elderly\n" in endpoints and "builtin:youthful\n" in endpoints
    assert '"style_id": "builtin:elderly"' in endpoints and '"frames": 40' in endpoints
    assert re.search(r'^"sty_[0-9a-f]{24}"$', endpoints, flags=re.M)  # the registered style, used by id
    assert endpoints.count('"inline"') == 0 and "\n204\n" in endpoints
    three = json.loads((tmp_path / "style3.json").read_text())  # a style from three clips, then used by id
    assert (three["clips"], three["frames"]) == (3, 270) and f'\n"{three["style_id"]}"\n' in endpoints
    assert frames_of(tmp_path / "transition.bvh") == 40
    assert '"name": "transition.bvh"' in endpoints  # the viewer's clip reader
    assert "rsmt_frames_generated_total" in (tmp_path / "metrics.txt").read_text()
    assert websocket.strip() == "40 arrived"


def test_the_client_readme_examples_run(server, tmp_path) -> None:
    outs = run_doc("clients/python/README.md", server, tmp_path)
    assert len(outs) == 4  # the minimal example, BVH files, the command line, failover
    minimal, _, commands, failover = outs.values()
    assert frames_of(tmp_path / "out.bvh") == 40 and frames_of(tmp_path / "turn.bvh") == 240
    assert "walk-elderly-turn-left" in commands and "builtin:elderly" in commands
    assert '"reason": "arrived"' in commands and '"frames": 40' in commands
    assert failover.strip() == "90 arrived 0"
