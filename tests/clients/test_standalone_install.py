"""``pip install ./clients/python`` alone, in a fresh virtual environment without the system's packages: the
client installs without torch (or the project) and runs transitions, HTTP and stream, against a real ``rsmt
serve`` started from the main environment, with the same numbers the main environment's client gets."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from rsmt_client import Client

from tests.clients.helpers import API_KEY, REPO

pytestmark = [pytest.mark.slow, pytest.mark.timeout(600)]

# Run by the fresh environment's Python, outside the repository: only what `pip install` put there is importable.
SCRIPT = r"""
import json, sys
from rsmt_client import Client, StreamClient, load_bvh_poses

url, key, context, target, style, out = sys.argv[1:]
with Client(url, api_key=key) as c:
    style_id = c.register_style(style, name="walk")["style_id"]
    poses = c.transition(context, target, 20, style_id=style_id, seed=7, deterministic=True)
    written = poses.save_bvh(out, c.model())
with StreamClient(url, api_key=key, encoding="binary") as s:
    streamed = s.transition(context, target, 20, style_id=style_id, seed=7, deterministic=True)
back = load_bvh_poses(written)
print(json.dumps({
    "loaded": sorted(m for m in sys.modules if m.split(".")[0] in ("torch", "model", "service", "rsmt_cli")),
    "style_id": style_id, "roots": poses.root_positions.tolist(), "rotations": poses.rotations.tolist(),
    "streamed": streamed.rotations.tolist(), "read_back": back.rotations.tolist(), "joints": list(back.joints),
}))
"""


def _run(cmd: list[str], env: dict[str, str], cwd: Path, timeout: float = 300) -> subprocess.CompletedProcess[str]:
    return subprocess.run(cmd, env=env, cwd=cwd, capture_output=True, text=True, timeout=timeout, check=False)


@pytest.fixture(scope="module")
def fresh_python(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, str]]:
    """A new virtual environment with only ``pip install <copy of clients/python>`` in it."""
    root = tmp_path_factory.mktemp("standalone")
    source = root / "rsmt-client"  # a copy: building writes metadata next to the sources
    shutil.copytree(REPO / "clients" / "python", source,
                    ignore=shutil.ignore_patterns("__pycache__", "*.egg-info", "build", "dist"))
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME", "VIRTUAL_ENV")}
    env.update(PIP_DISABLE_PIP_VERSION_CHECK="1", PIP_NO_INPUT="1")
    made = _run([sys.executable, "-m", "venv", str(root / "venv")], env, root)
    assert made.returncode == 0, made.stderr
    python = root / "venv" / "bin" / "python"
    installed = _run([str(python), "-m", "pip", "install", "--quiet", str(source)], env, root)
    assert installed.returncode == 0, installed.stdout[-3000:] + installed.stderr[-3000:]
    return python, env


def test_installs_without_torch(fresh_python):
    python, env = fresh_python
    cwd = python.parents[2]
    assert _run([str(python), "-m", "pip", "show", "rsmt-client"], env, cwd).returncode == 0
    assert _run([str(python), "-m", "pip", "show", "torch"], env, cwd).returncode != 0
    for module in ("torch", "model", "rsmt_cli"):
        probe = _run([str(python), "-c", f"import {module}"], env, cwd)
        assert probe.returncode != 0 and "ModuleNotFoundError" in probe.stderr, module
    version = _run([str(python), "-c", "import rsmt_client; print(rsmt_client.__version__)"], env, cwd)
    assert version.returncode == 0 and version.stdout.strip() == "0.1.0", version.stderr


def test_transition_from_the_fresh_environment(fresh_python, server, motions, tmp_path):
    python, env = fresh_python
    out = tmp_path / "out.bvh"
    proc = _run([str(python), "-c", SCRIPT, server.url, API_KEY, str(motions["context"]), str(motions["target"]),
                 str(motions["style"]), str(out)], env, tmp_path, timeout=120)
    assert proc.returncode == 0, proc.stderr[-3000:]
    got = json.loads(proc.stdout)
    assert got["loaded"] == []  # nothing of torch or the project was imported
    with Client(server.url, api_key=API_KEY) as c:
        here = c.transition(motions["context"], motions["target"], 20, style_id=got["style_id"], seed=7,
                            deterministic=True)
        joints = [j["name"] for j in c.model()["skeleton"]["joints"]]
    np.testing.assert_array_equal(np.array(got["rotations"], np.float32), here.rotations)
    np.testing.assert_array_equal(np.array(got["roots"], np.float32), here.root_positions)
    np.testing.assert_allclose(np.array(got["streamed"]), here.rotations, atol=1e-4)
    # The BVH it wrote (numpy only) reads back to the same rotations on the served skeleton.
    assert got["joints"] == joints and out.is_file()
    back, sent = np.array(got["read_back"]), here.rotations.astype(np.float64)
    assert np.minimum(np.abs(back - sent).max(-1), np.abs(back + sent).max(-1)).max() < 1e-5
