"""The layout rules the code keeps: dependencies point one way, no import cycles, small modules.

Read from the source with :mod:`ast` (nothing is imported), so a rule broken anywhere fails here
with the modules named.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PACKAGES = {"model": REPO / "model", "service": REPO / "service", "rsmt_cli": REPO / "rsmt_cli",
            "rsmt_client": REPO / "clients" / "python" / "rsmt_client"}
MAX_LINES = 500
MAX_MODEL_TOP_LEVEL = 8


def _modules() -> dict[str, Path]:
    found = {}
    for top, folder in PACKAGES.items():
        for path in folder.rglob("*.py"):
            parts = [top, *path.relative_to(folder).with_suffix("").parts]
            if parts[-1] == "__init__":
                parts = parts[:-1]
            found[".".join(parts)] = path
    return found


MODULES = _modules()


def _imports(name: str, path: Path) -> set[str]:
    """Every module of this repository that ``name`` imports, at any depth of its code (lazy imports count)."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    out: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        targets: list[str] = []
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join([*anchor, base] if base else anchor)
            # "from pkg import mod" imports the module pkg.mod when there is one, else names of pkg.
            targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in MODULES else base for a in node.names]
        for target in targets:
            while target and target not in MODULES:
                target = target.rpartition(".")[0]
            if target and target != name:
                out.add(target)
    return out


GRAPH = {name: _imports(name, path) for name, path in MODULES.items()}


def _reaches(start: str) -> set[str]:
    seen, stack = set(), [start]
    while stack:
        for nxt in GRAPH[stack.pop()]:
            if nxt not in seen:
                seen.add(nxt)
                stack.append(nxt)
    return seen


def test_the_graph_was_read():
    assert len(MODULES) > 60
    assert "model.inference.engine" in GRAPH["service.app"] | _reaches("service.app")
    assert "model.motion.rotations" in GRAPH["model.motion.kinematics"]


def test_no_import_cycles():
    cycles = sorted(name for name in GRAPH if name in _reaches(name))
    assert not cycles, f"modules on an import cycle: {', '.join(cycles)}"


@pytest.mark.parametrize(("low", "high"), [("model", "service"), ("model", "rsmt_cli"), ("model", "rsmt_client"),
                                           ("rsmt_client", "model"), ("rsmt_client", "service"),
                                           ("rsmt_client", "rsmt_cli"), ("service", "rsmt_cli")])
def test_dependencies_point_one_way(low, high):
    wrong = sorted(f"{name} -> {dep}" for name, deps in GRAPH.items() if name.split(".")[0] == low
                   for dep in deps if dep.split(".")[0] == high)
    assert not wrong, f"{low} must not import {high}: {'; '.join(wrong)}"


# Inside model/: the layers, bottom up, and what each must never import (model.<layer> and anything in it).
MODEL_LAYERS = {
    "motion": {"retrieval", "nets", "data", "inference", "export", "evaluation", "train", "bench"},  # nothing of the project
    "retrieval": {"nets", "data", "inference", "export", "evaluation", "train", "bench"},  # motion only
    "nets": {"data", "inference", "export", "evaluation", "train", "bench"},  # motion and retrieval
    "data": {"inference", "export", "evaluation", "train", "bench"},
    "inference": {"data", "export", "evaluation", "train", "bench"},
    "export": {"evaluation", "train", "bench"},  # the engine's graphs for other runtimes, over inference
}


def _model_layer(module: str) -> str | None:
    parts = module.split(".")
    return parts[1] if parts[0] == "model" and len(parts) > 1 else None


@pytest.mark.parametrize("layer", sorted(MODEL_LAYERS))
def test_model_layers_point_down(layer):
    banned = MODEL_LAYERS[layer]
    wrong = sorted(f"{name} -> {dep}" for name, deps in GRAPH.items() if _model_layer(name) == layer
                   for dep in deps if _model_layer(dep) in banned or dep.split(".")[0] != "model")
    assert not wrong, f"model.{layer} must not import {', '.join(sorted(banned))} (nor outside model): {'; '.join(wrong)}"


def test_the_model_layers_are_known():
    """Every part of model/ is a layer the rules name, or one of the layers above them (evaluation, train,
    the bench), so a new folder has to be placed."""
    parts = {_model_layer(name) for name in GRAPH} - {None}
    assert parts <= set(MODEL_LAYERS) | {"evaluation", "train", "bench", "default_bundle"}, parts


def test_the_client_imports_no_torch():
    names = set()
    for name, path in MODULES.items():
        if name.startswith("rsmt_client"):
            for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
                if isinstance(node, ast.Import):
                    names |= {a.name.split(".")[0] for a in node.names}
                elif isinstance(node, ast.ImportFrom) and not node.level and node.module:
                    names.add(node.module.split(".")[0])
    assert not names & {"torch", "fastapi", "matplotlib", "model", "service"}


def test_modules_are_small():
    big = sorted(f"{path.relative_to(REPO)} ({n} lines)" for path in MODULES.values()
                 if (n := len(path.read_text(encoding="utf-8").splitlines())) > MAX_LINES)
    assert not big, f"modules over {MAX_LINES} lines: {', '.join(big)}"


def test_model_top_level_holds_few_modules():
    top = sorted(p.name for p in (REPO / "model").glob("*.py"))
    assert len(top) <= MAX_MODEL_TOP_LEVEL, f"model/ holds {len(top)} modules at its top level: {', '.join(top)}"


# Inside service/: its rooms (each top-level module, each subpackage with all it holds) import one another without
# a cycle, so the service reads as floors, each standing on the ones below.
def _service_room(module: str) -> str | None:
    parts = module.split(".")
    return parts[1] if parts[0] == "service" and len(parts) > 1 else None


def _service_arrows() -> dict[tuple[str, str], set[str]]:
    """``(room, room it imports)`` -> the files that make that arrow (TYPE_CHECKING and lazy imports count)."""
    arrows: dict[tuple[str, str], set[str]] = {}
    for name, deps in GRAPH.items():
        src = _service_room(name)
        for dep in deps:
            dst = _service_room(dep)
            if src and dst and src != dst:
                arrows.setdefault((src, dst), set()).add(str(MODULES[name].relative_to(REPO)))
    return arrows


def _path(arrows: dict[tuple[str, str], set[str]], start: str, goal: str) -> list[str] | None:
    """The rooms of a shortest chain of arrows from ``start`` to ``goal`` (None when there is none)."""
    before: dict[str, str] = {start: start}
    frontier = [start]
    while frontier:
        nxt = []
        for room in frontier:
            for src, dst in arrows:
                if src == room and dst not in before:
                    before[dst] = room
                    nxt.append(dst)
        frontier = nxt
    if goal not in before:
        return None
    chain = [goal]
    while chain[-1] != start:
        chain.append(before[chain[-1]])
    return chain[::-1]


def test_service_rooms_have_no_cycles():
    arrows = _service_arrows()
    assert ("routes", "registry") in arrows or ("routes", "deps") in arrows, "the service's graph was not read"
    found = []
    for src, dst in sorted(arrows):
        back = _path(arrows, dst, src)
        if back is not None:
            chain = [src, *back]
            found.append(" -> ".join(chain) + ": " + "; ".join(
                f"{a} -> {b} ({', '.join(sorted(arrows[(a, b)]))})" for a, b in zip(chain, chain[1:])))
    assert not found, "service/ rooms on an import cycle (move the code to the floor it belongs on):\n" + "\n".join(found)


def test_styles_are_reached_through_their_face():
    """Style handling is one subpackage; the rest of the code imports what ``service/styles/__init__.py`` names,
    never a module inside it (which can then move without touching its users)."""
    assert "service.styles.jobs" in MODULES and "service.styles" in GRAPH["service.routes.styles"]
    inside = [f"{name} -> {dep}" for name, deps in sorted(GRAPH.items()) if not name.startswith("service.styles")
              for dep in sorted(deps) if dep.startswith("service.styles.")]
    assert not inside, f"import these from service.styles (add them to its __init__ if missing): {'; '.join(inside)}"
