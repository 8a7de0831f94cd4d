"""A Docker daemon for tests/deploy/test_image.py, and what its builds need on a machine without Docker Hub.

* :class:`DockerDaemon`: the running daemon, or one started here (root, Debian's ``docker.io``) and stopped by
  its PID afterwards; tests skip with the reason where none can start.
* :func:`debian_base`: ``deploy/docker/debian-base.sh``, a debootstrap bookworm base with Python 3.11 (its root
  filesystem cached under ``~/.cache/rsmt-image``), imported as an image.
* :class:`WheelFolder`: every wheel the image needs, downloaded once by the host's pip into the same cache and
  linked into ``deploy/docker/wheels/`` for a build, so the build runs offline (``--network none``).
"""

from __future__ import annotations

import hashlib
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
CACHE = Path(os.environ.get("RSMT_IMAGE_CACHE", Path.home() / ".cache" / "rsmt-image"))
WHEELS = ROOT / "deploy" / "docker" / "wheels"
START_S = 90.0


def docker(*args: str, timeout: float = 120.0, check: bool = True, env: dict[str, str] | None = None,
           nice: bool = False) -> subprocess.CompletedProcess[str]:
    """``docker ARGS``; a failure raises with the command's output. The legacy builder: the same with
    Debian's client and a newer one without the buildx plugin."""
    cmd = (["nice", "-n", "10"] if nice else []) + ["docker", *args]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout,
                          env={**os.environ, "DOCKER_BUILDKIT": "0", **(env or {})})
    if check and done.returncode != 0:
        raise AssertionError(f"{' '.join(cmd)} exited {done.returncode}:\n{done.stdout[-3000:]}\n{done.stderr[-3000:]}")
    return done


def _daemon_answers() -> bool:
    try:
        return subprocess.run(["docker", "info"], capture_output=True, timeout=20).returncode == 0
    except (OSError, subprocess.TimeoutExpired):
        return False


class DockerDaemon:
    """The daemon ``docker`` talks to: the one already running, or ``dockerd`` started here and stopped after."""

    def __init__(self) -> None:
        self.proc: subprocess.Popen[bytes] | None = None
        self.log: Path | None = None

    def start(self) -> DockerDaemon:
        if shutil.which("docker") is None:
            pytest.skip("no docker client (apt-get install -y docker.io; .ci/run does it)")
        if _daemon_answers():
            return self
        dockerd = shutil.which("dockerd")
        if dockerd is None:
            pytest.skip("no Docker daemon runs and dockerd is not installed (apt-get install -y docker.io)")
        if os.geteuid() != 0:
            pytest.skip("no Docker daemon runs and only root can start dockerd here")
        self.log = Path(tempfile.mkdtemp(prefix="rsmt-dockerd-")) / "dockerd.log"
        with self.log.open("wb") as out:  # nice: the builds and containers it starts inherit the priority
            self.proc = subprocess.Popen(["nice", "-n", "10", dockerd], stdout=out, stderr=subprocess.STDOUT)
        deadline = time.monotonic() + START_S
        while time.monotonic() < deadline and self.proc.poll() is None:
            if _daemon_answers():
                return self
            time.sleep(1.0)
        tail = self.log.read_text(errors="replace")[-2000:]
        self.stop()
        pytest.skip(f"dockerd could not start here (no daemon can run in this environment):\n{tail}")

    def stop(self) -> None:
        """Stop the daemon started here (by its PID); one that was already running is left alone."""
        if self.proc is None or self.proc.poll() is not None:
            return
        self.proc.send_signal(signal.SIGTERM)
        try:
            self.proc.wait(60)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait(10)


def remove_image_tree(image: str) -> None:
    """Remove ``image`` and every image built on it, the legacy builder's intermediate layers too (``docker rmi``
    of a tag leaves those of an earlier stage behind); images that do not descend from it are left alone."""
    root = docker("image", "inspect", "-f", "{{.Id}}", image, check=False).stdout.strip()
    if not root:
        return
    ids = docker("images", "-aq", "--no-trunc").stdout.split()
    parent = dict(line.split(" ", 1) for line in docker("inspect", "-f", "{{.Id}} {{.Parent}}", *ids).stdout.splitlines())

    def depth(i: str) -> int:  # steps from root, or -1 when root is not an ancestor
        n = 0
        while i and i != root:
            i, n = parent.get(i, ""), n + 1
        return n if i == root else -1

    tree = sorted((i for i in ids if depth(i) >= 0), key=depth, reverse=True)  # children first
    for i in dict.fromkeys(tree):
        docker("rmi", "-f", i, check=False)


def debian_base(tag: str) -> str:
    """The debootstrap bookworm base (python3, python3-venv) imported as ``tag``."""
    if shutil.which("debootstrap") is None:
        pytest.skip("debootstrap is not installed (apt-get install -y debootstrap; .ci/run does it)")
    done = subprocess.run(["bash", str(ROOT / "deploy" / "docker" / "debian-base.sh"), tag], capture_output=True,
                          text=True, timeout=900, env={**os.environ, "RSMT_IMAGE_CACHE": str(CACHE)})
    assert done.returncode == 0, f"debian-base.sh exited {done.returncode}:\n{done.stderr[-3000:]}"
    return tag


class WheelFolder:
    """Every wheel the image installs, for Python 3.11 on x86-64, from the host's pip (its configured indexes
    and wheel folders: the CPU torch wheel is one of them here). Cached per version of the two pyproject
    files; :meth:`link` puts them in ``deploy/docker/wheels/`` for a build, :meth:`unlink` takes them out."""

    # async-timeout: redis requires it on Python < 3.11.3 (Debian bookworm has 3.11.2), whatever the host's
    # Python. setuptools and wheel: the build backend of both projects, installed offline as well.
    EXTRA = ["async-timeout>=4.0.3", "setuptools>=69", "wheel"]

    def __init__(self) -> None:
        key = hashlib.sha256()
        for p in (ROOT / "pyproject.toml", ROOT / "clients" / "python" / "pyproject.toml"):
            key.update(p.read_bytes())
        self.dir = CACHE / f"wheels-{key.hexdigest()[:16]}"
        self.linked: list[Path] = []

    def ensure(self) -> WheelFolder:
        if (self.dir / "COMPLETE").is_file():
            return self
        part = Path(tempfile.mkdtemp(prefix="wheels.", dir=CACHE))
        try:
            done = subprocess.run(
                ["nice", "-n", "10", sys.executable, "-m", "pip", "download", "--quiet", "--dest", str(part),
                 "torch==2.13.0", str(ROOT / "clients" / "python"), str(ROOT), *self.EXTRA],
                capture_output=True, text=True, timeout=900)
            assert done.returncode == 0, f"pip download exited {done.returncode}:\n{done.stderr[-3000:]}"
            torch = [w.name for w in part.glob("torch-*.whl")]
            assert torch and all("+cpu" in w for w in torch), f"not the CPU torch wheel: {torch}"
            (part / "COMPLETE").touch()
            shutil.rmtree(self.dir, ignore_errors=True)
            part.rename(self.dir)
        finally:
            shutil.rmtree(part, ignore_errors=True)
        return self

    def link(self) -> None:
        for wheel in sorted(self.dir.glob("*.whl")):
            dest = WHEELS / wheel.name
            if dest.exists():
                continue
            try:
                os.link(wheel, dest)
            except OSError:  # another file system
                shutil.copy2(wheel, dest)
            self.linked.append(dest)

    def unlink(self) -> None:
        for dest in self.linked:
            dest.unlink(missing_ok=True)
        self.linked.clear()
