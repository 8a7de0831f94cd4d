"""deploy/: the Kubernetes manifests against the Kubernetes schemas (kubernetes-validate, offline), the
kustomize-rendered base and example overlay when a renderer is installed, and the compose topology's
references (compose.yaml, deploy/haproxy.cfg) checked against each other and against the service's settings."""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

import pytest
import yaml

from service.settings import Settings

kv = pytest.importorskip("kubernetes_validate", reason="pip install -e '.[test]' brings kubernetes-validate")

ROOT = Path(__file__).resolve().parents[2]
BASE = ROOT / "deploy" / "kubernetes" / "base"
OVERLAY = ROOT / "deploy" / "kubernetes" / "overlays" / "example"
K8S_VERSION = "1.30.0"  # the oldest Kubernetes these manifests are written for (autoscaling/v2, policy/v1)


def docs(path: Path) -> list[dict[str, Any]]:
    return [d for d in yaml.safe_load_all(path.read_text()) if d]


def base_resources() -> list[dict[str, Any]]:
    kustomization = docs(BASE / "kustomization.yaml")[0]
    return [d for name in kustomization["resources"] for d in docs(BASE / name)]


def by_kind(resources: list[dict[str, Any]], kind: str, name: str | None = None) -> dict[str, Any]:
    found = [r for r in resources if r["kind"] == kind and (name is None or r["metadata"]["name"] == name)]
    assert len(found) == 1, f"{kind} {name}: {len(found)} found"
    return found[0]


def validate_all(resources: list[dict[str, Any]]) -> None:
    for r in resources:
        try:
            kv.validate(r, K8S_VERSION, strict=True)
        except kv.ValidationError as exc:  # the path and message of the first problem
            raise AssertionError(f"{r['kind']}/{r['metadata']['name']}: {exc.message} at {list(exc.path)}") from exc


def test_every_base_manifest_is_valid_kubernetes():
    resources = base_resources()
    assert {r["kind"] for r in resources} == {"ConfigMap", "Deployment", "Service", "HorizontalPodAutoscaler",
                                              "PodDisruptionBudget", "Ingress"}
    validate_all(resources)
    validate_all(docs(OVERLAY / "external-redis.yaml"))


def render() -> list[str] | None:
    if shutil.which("kubectl"):
        return ["kubectl", "kustomize"]
    if shutil.which("kustomize"):
        return ["kustomize", "build"]
    return None


@pytest.mark.parametrize("target", [BASE, OVERLAY], ids=["base", "overlay-example"])
def test_kustomize_output_is_valid_kubernetes(target):
    command = render()
    if command is None:
        pytest.skip("neither kubectl nor kustomize is installed: the files were validated one by one")
    out = subprocess.run([*command, str(target)], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    resources = [d for d in yaml.safe_load_all(out.stdout) if d]
    validate_all(resources)
    if target == OVERLAY:
        assert all(r["metadata"].get("namespace") == "rsmt" for r in resources)
        assert "rsmt-redis" not in {r["metadata"]["name"] for r in resources}  # the managed Redis replaces it
        config = by_kind(resources, "ConfigMap")["data"]
        assert Settings(style_store=config["RSMT_STYLE_STORE"]).style_store.startswith("rediss://")
        image = by_kind(resources, "Deployment")["spec"]["template"]["spec"]["containers"][0]["image"]
        assert image == "registry.example.com/games/rsmt:0.1.0"


def _check_pod(pod: dict[str, Any], container: dict[str, Any], settings: Settings) -> None:
    """Probes, shutdown timing, security context, writable /tmp and resource bounds of the rsmt pod."""
    assert container["readinessProbe"]["httpGet"]["path"] == "/v1/health/ready"
    assert container["livenessProbe"]["httpGet"]["path"] == "/v1/health/live"
    assert pod["terminationGracePeriodSeconds"] >= settings.shutdown_drain_s + settings.shutdown_grace_s + 1
    assert settings.shutdown_drain_s >= 2 * container["readinessProbe"]["periodSeconds"]  # out of endpoints first
    assert pod["securityContext"]["runAsNonRoot"] is True and pod["securityContext"]["runAsUser"] != 0
    assert container["securityContext"]["readOnlyRootFilesystem"] is True
    tmp = {m["name"] for m in container["volumeMounts"] if m["mountPath"] == "/tmp"}
    assert tmp and all("emptyDir" in v for v in pod["volumes"] if v["name"] in tmp)
    for kind in ("requests", "limits"):
        assert {"cpu", "memory"} <= set(container["resources"][kind])


def _check_routing(resources: list[dict[str, Any]], container: dict[str, Any], labels: dict[str, Any],
                   settings: Settings) -> None:
    """Service, PodDisruptionBudget, autoscaler, Ingress and the style store all point at the rsmt pods."""
    service = by_kind(resources, "Service", "rsmt")
    assert service["spec"]["selector"].items() <= labels.items()
    assert service["spec"]["ports"][0]["targetPort"] in {p["name"] for p in container["ports"]}
    assert by_kind(resources, "PodDisruptionBudget")["spec"]["selector"]["matchLabels"].items() <= labels.items()
    hpa = by_kind(resources, "HorizontalPodAutoscaler")
    assert hpa["spec"]["scaleTargetRef"]["name"] == "rsmt" and hpa["spec"]["minReplicas"] >= 2
    ingress = by_kind(resources, "Ingress")
    notes = ingress["metadata"]["annotations"]
    assert notes["nginx.ingress.kubernetes.io/affinity"] == "cookie"
    assert int(notes["nginx.ingress.kubernetes.io/proxy-read-timeout"]) >= 600  # WebSockets stay open
    backend = ingress["spec"]["rules"][0]["http"]["paths"][0]["backend"]["service"]
    assert backend["name"] == "rsmt" and backend["port"]["name"] == service["spec"]["ports"][0]["name"]
    store = urlsplit(settings.style_store)
    redis = by_kind(resources, "Service", "rsmt-redis")
    assert store.hostname == "rsmt-redis" and store.port == redis["spec"]["ports"][0]["port"]


def test_deployment_fits_the_service():
    resources = base_resources()
    config = by_kind(resources, "ConfigMap", "rsmt-config")["data"]
    fields = {f"RSMT_{name.upper()}" for name in Settings.model_fields}
    assert set(config) <= fields, set(config) - fields  # every key is a setting
    settings = Settings(**{k[5:].lower(): v for k, v in config.items()})  # and every value parses
    deploy = by_kind(resources, "Deployment", "rsmt")
    pod = deploy["spec"]["template"]["spec"]
    (container,) = pod["containers"]
    _check_pod(pod, container, settings)
    labels = pod and deploy["spec"]["template"]["metadata"]["labels"]
    _check_routing(resources, container, labels, settings)


# ---------------------------------------------------------------------- compose.yaml and deploy/haproxy.cfg

def compose() -> dict[str, Any]:
    return yaml.safe_load((ROOT / "compose.yaml").read_text())


def haproxy_servers(text: str) -> dict[str, list[tuple[str, int]]]:
    """backend name -> [(host, port)] of its server lines."""
    out: dict[str, list[tuple[str, int]]] = {}
    backend = None
    for line in text.splitlines():
        words = line.split()
        if words[:1] == ["backend"]:
            backend = words[1]
            out[backend] = []
        elif words[:1] in (["frontend"], ["defaults"], ["global"], ["resolvers"]):
            backend = None
        elif words[:1] == ["server"] and backend is not None:
            host, port = words[2].rsplit(":", 1)
            out[backend].append((host, int(port)))
    return out


def test_compose_topology_is_consistent():
    spec = compose()
    services = spec["services"]
    replicas = sorted(s for s in services if re.fullmatch(r"rsmt-\d+", s))
    assert len(replicas) == 3 and {"redis", "haproxy"} <= set(services)
    for name in replicas:
        env = services[name]["environment"]
        store = urlsplit(Settings(style_store=env["RSMT_STYLE_STORE"]).style_store)
        assert store.hostname in services and (store.port or 6379) == 6379
        assert services[name]["depends_on"]["redis"]["condition"] == "service_healthy"
        assert services[name]["read_only"] is True and "/tmp" in services[name]["tmpfs"]
    lb = services["haproxy"]
    mounts = {m.split(":")[1]: m.split(":")[0] for m in lb["volumes"]}
    cfg = ROOT / mounts["/usr/local/etc/haproxy/haproxy.cfg"]
    assert cfg.resolve() == (ROOT / "deploy" / "haproxy.cfg").resolve() and cfg.is_file()
    text = cfg.read_text()
    backends = haproxy_servers(text)
    assert set(backends) == {"rsmt_http", "rsmt_ws"}
    for servers in backends.values():
        assert sorted(h for h, _ in servers) == replicas and {p for _, p in servers} == {8000}  # the image's port
    assert re.search(r"backend rsmt_http\n\s+balance leastconn", text)
    assert re.search(r"backend rsmt_ws\n\s+balance source", text)
    assert re.search(r"use_backend rsmt_ws if stream", text) and "acl stream path_beg /v1/stream" in text
    bind = re.search(r"^\s*bind :(\d+)", text, re.M)
    published = lb["ports"][0].rsplit(":", 2)
    assert bind and published[-1] == bind.group(1)
    assert set(lb["depends_on"]) == set(replicas)


def test_haproxy_accepts_the_config():
    if shutil.which("haproxy") is None:
        pytest.skip("haproxy is not installed (apt-get install -y haproxy; .ci/run does it)")
    out = subprocess.run(["haproxy", "-c", "-f", str(ROOT / "deploy" / "haproxy.cfg")], capture_output=True,
                         text=True, timeout=30)
    assert out.returncode == 0, out.stdout + out.stderr  # names of compose services do not resolve here: warnings only
