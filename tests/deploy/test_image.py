"""The Dockerfile built and run for real, and compose.yaml's topology brought up as containers.

Docker Hub is out of reach here, so the image is built ``--build-arg BASE=`` a Debian bookworm base made with
debootstrap (``deploy/docker/debian-base.sh``) and from a local wheel folder (``deploy/docker/wheels/``) with
``--network none``: the same Dockerfile a user builds on python:3.11-slim. The container must report
HEALTHCHECK ``healthy``, run as a user other than root, answer a transition on its published port, and exit 0
on ``docker stop`` (SIGKILL after docker's 10 s would be 137: the drain fits). The image's size is printed
and held to 1.3 GB. Then compose.yaml (three replicas, Redis, HAProxy) runs with Redis and HAProxy from
Debian's packages (tests/deploy/containers/) and answers a style and transitions through the load balancer.
Skipped with the reason where no Docker daemon can start (not root, no docker.io); every image, container,
network and volume made here is removed at the end.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import tempfile
import time
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import httpx
import pytest

from tests.deploy.docker_host import ROOT, DockerDaemon, WheelFolder, debian_base, docker, remove_image_tree
from tests.service.server import free_port

pytestmark = [pytest.mark.slow, pytest.mark.timeout(1500)]
MAX_IMAGE_BYTES = 1.3e9  # the limit (on python:3.11-slim; the debootstrap base is about as large)
HEALTHY_S = 300.0  # model load and warm-up on a small, busy machine, plus a HEALTHCHECK interval
SERVICES = ROOT / "tests" / "deploy" / "containers"


@dataclass
class Images:
    base: str
    rsmt: str
    services: str
    seconds: dict[str, float]  # how long each step took: printed, never asserted


@pytest.fixture(scope="module")
def images() -> Iterator[Images]:
    daemon = DockerDaemon().start()
    tag = f"rsmt-imagetest-{os.getpid()}"
    made = Images(base=f"{tag}-base:bookworm", rsmt=f"{tag}:latest", services=f"{tag}-services:latest", seconds={})
    stage = f"{tag}-build:latest"  # the build stage, tagged so that removing it removes its layers
    wheels = WheelFolder()
    try:
        t0 = time.monotonic()
        debian_base(made.base)
        made.seconds["debootstrap base"] = (t1 := time.monotonic()) - t0
        wheels.ensure().link()
        made.seconds["wheels"] = (t0 := time.monotonic()) - t1
        try:
            for target in (["--target", "build", "-t", stage], ["-t", made.rsmt]):  # the second from the cache
                docker("build", "--force-rm", "--network", "none", "--build-arg", f"BASE={made.base}", *target, str(ROOT),
                       timeout=1200, nice=True)
        finally:
            wheels.unlink()
        made.seconds["docker build"] = time.monotonic() - t0
        docker("build", "--force-rm", "--build-arg", f"BASE={made.base}", "-t", made.services, "-f",
               str(SERVICES / "services.Dockerfile"), str(SERVICES), timeout=600, nice=True)
        yield made
    finally:
        remove_image_tree(made.base)  # everything built here descends from it
        daemon.stop()


def inspect(container: str, fmt: str) -> str:
    return docker("inspect", "-f", fmt, container).stdout.strip()


def wait_healthy(containers: list[str]) -> None:
    """Until every container's HEALTHCHECK says ``healthy``; one that exits or turns unhealthy fails at once."""
    deadline = time.monotonic() + HEALTHY_S
    states: dict[str, str] = {}
    while time.monotonic() < deadline:
        for c in containers:
            states[c] = inspect(c, "{{.State.Status}} {{if .State.Health}}{{.State.Health.Status}}{{end}}")
            if states[c].split()[0] != "running" or states[c].endswith("unhealthy"):
                logs = docker("logs", "--tail", "40", c, check=False)
                raise AssertionError(f"{c}: {states[c]}\n{logs.stdout[-3000:]}{logs.stderr[-3000:]}")
        if all(s == "running healthy" for s in states.values()):
            return
        time.sleep(2.0)
    raise AssertionError(f"not healthy within {HEALTHY_S} s: {states}")


def walk(url: str, headers: dict[str, str] | None = None) -> dict[str, Any]:
    """The default model's captured walk (JSON poses), as docs/service.md's examples fetch it."""
    r = httpx.get(f"{url}/v1/viewer/demos/walk-normal", headers=headers, timeout=60)
    assert r.status_code == 200, r.text
    return r.json()


def poses(w: dict[str, Any], a: int, b: int) -> dict[str, Any]:
    return {"root_positions": w["root_positions"][a:b], "rotations": w["rotations"][a:b]}


def transition(url: str, w: dict[str, Any], style_id: str) -> dict[str, Any]:
    body = {"context": poses(w, 50, 60), "target": poses(w, 98, 100), "frames": 40, "style_id": style_id, "seed": 7}
    r = httpx.post(f"{url}/v1/transition", json=body, timeout=120)
    assert r.status_code == 200, r.text
    out = r.json()
    assert len(out["frames"]) == 40 and out["style_id"] == style_id and out["model"] == "rsmt-default"
    return out


def test_the_image_is_healthy_non_root_serves_and_stops_within_the_drain(images: Images) -> None:
    size = int(docker("image", "inspect", "-f", "{{.Size}}", images.rsmt).stdout)
    base = int(docker("image", "inspect", "-f", "{{.Size}}", images.base).stdout)
    took = ", ".join(f"{step} {s:.0f} s" for step, s in images.seconds.items())
    print(f"\nimage {size / 1e9:.2f} GB ({size} bytes; debootstrap base {base / 1e6:.0f} MB); {took}")
    assert size <= MAX_IMAGE_BYTES
    # Nothing of the project but the packages: no checkout, tests or docs.
    found = docker("run", "--rm", "--network", "none", "--user", "0", "--entrypoint", "sh", images.rsmt, "-c",
                   "ls -d /src /wheels 2>/dev/null; find / -xdev \\( -name test_architecture.py -o -name api-contract.md "
                   "-o -path '*/tests/deploy*' \\) -print").stdout
    assert found == ""

    name = f"{images.rsmt.split(':')[0]}-one"
    t0 = time.monotonic()
    docker("run", "-d", "--name", name, "-p", "127.0.0.1::8000", images.rsmt)
    try:
        wait_healthy([name])
        print(f"healthy {time.monotonic() - t0:.0f} s after docker run")
        assert docker("exec", name, "id", "-u").stdout.strip() == "10001"
        assert inspect(name, "{{.Config.User}}") == "10001:10001"
        port = docker("port", name, "8000/tcp").stdout.split()[0].rsplit(":", 1)[1]
        url = f"http://127.0.0.1:{port}"
        transition(url, walk(url), "builtin:elderly")

        t0 = time.monotonic()
        stopped = docker("stop", name, timeout=60)  # docker's own 10 s, then SIGKILL (exit 137)
        print(f"docker stop: {time.monotonic() - t0:.1f} s")
        assert stopped.returncode == 0
        assert inspect(name, "{{.State.ExitCode}} {{.State.OOMKilled}}") == "0 false"
        logs = docker("logs", name)
        assert '"event": "stopped"' in logs.stdout + logs.stderr  # the service's own last word: a clean exit
    finally:
        docker("rm", "-f", "-v", name, check=False)  # -v: the anonymous /models volume


def compose_command() -> list[str]:
    for cmd in (["docker", "compose"], ["docker-compose"]):
        if shutil.which(cmd[0]) and subprocess.run([*cmd, "version"], capture_output=True).returncode == 0:
            return cmd
    pytest.skip("neither `docker compose` nor docker-compose is installed (apt-get install -y docker-compose)")


class Topology:
    """compose.yaml with tests/deploy/containers/compose.debian.yaml over it, as project ``rsmt-imagetest-PID``."""

    def __init__(self, images: Images) -> None:
        self.models = tempfile.mkdtemp(prefix="rsmt-models-")
        port = free_port()
        self.url = f"http://127.0.0.1:{port}"
        self.env = {**os.environ, "RSMT_TEST_IMAGE": images.rsmt, "RSMT_TEST_SERVICES_IMAGE": images.services,
                    "RSMT_TEST_MODELS": self.models, "RSMT_PORT": str(port)}
        self.compose = [*compose_command(), "-p", f"rsmt-imagetest-{os.getpid()}", "-f", str(ROOT / "compose.yaml"),
                        "-f", str(SERVICES / "compose.debian.yaml")]

    def run(self, *args: str, check: bool = True, timeout: float = 600) -> subprocess.CompletedProcess[str]:
        done = subprocess.run([*self.compose, *args], capture_output=True, text=True, timeout=timeout, env=self.env,
                              cwd=ROOT)
        if check:
            assert done.returncode == 0, f"compose {' '.join(args)} exited {done.returncode}:\n{done.stderr[-3000:]}"
        return done

    def container(self, service: str) -> str:
        cid = self.run("ps", "-q", service).stdout.strip()
        assert cid, f"no container for {service}"
        return cid


@pytest.fixture
def topology(images: Images) -> Iterator[Topology]:
    top = Topology(images)
    try:
        top.run("up", "-d", "--no-build")
        yield top
        # Every replica drains and exits 0 inside compose.yaml's stop_grace_period.
        replicas = [top.container(s) for s in ("rsmt-1", "rsmt-2", "rsmt-3")]
        top.run("stop")
        assert [inspect(c, "{{.State.ExitCode}}") for c in replicas] == ["0", "0", "0"]
    finally:
        top.run("down", "--volumes", "--remove-orphans", "--timeout", "20", check=False, timeout=300)
        shutil.rmtree(top.models, ignore_errors=True)


def test_compose_topology_serves_a_style_through_the_load_balancer(topology: Topology) -> None:
    ids = {s: topology.container(s) for s in ("rsmt-1", "rsmt-2", "rsmt-3", "redis", "haproxy")}
    wait_healthy([ids[s] for s in ("rsmt-1", "rsmt-2", "rsmt-3", "redis")])  # HAProxy has no HEALTHCHECK
    url = topology.url
    lb_ready(url)

    w = walk(url)
    r = httpx.post(f"{url}/v1/styles", json={"name": "walk", "motion": poses(w, 0, 90)}, timeout=120)
    assert r.status_code == 201, r.text
    sid = r.json()["style_id"]
    for _ in range(6):  # least-connections over three replicas
        transition(url, w, sid)
    # Every replica knows the style from the shared Redis store, whichever registered it.
    probe = ("import json, urllib.request; "
             f"print(json.load(urllib.request.urlopen('http://127.0.0.1:8000/v1/styles/{sid}', timeout=30))['style_id'])")
    for s in ("rsmt-1", "rsmt-2", "rsmt-3"):
        assert docker("exec", ids[s], "python", "-c", probe).stdout.strip() == sid, s
    assert int(docker("exec", ids["redis"], "redis-cli", "dbsize").stdout) > 0


def lb_ready(url: str) -> None:
    """HAProxy sends traffic once its checks have seen a replica ready twice (deploy/haproxy.cfg: rise 2)."""
    deadline = time.monotonic() + 60.0
    while time.monotonic() < deadline:
        try:
            if httpx.get(f"{url}/v1/health/ready", timeout=5).status_code == 200:
                return
        except httpx.HTTPError:
            pass
        time.sleep(1.0)
    raise AssertionError(f"the load balancer at {url} did not answer ready within 60 s")
