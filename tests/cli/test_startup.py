"""``rsmt --help``, a command's ``--help`` and ``rsmt client ...`` start without torch, the model or the service.

Building the parser imports only argparse definitions; torch and the rest load inside the command
that needs them. ``rsmt client ...`` imports only the client group and what its command uses (no numpy
to list styles, no WebSocket library outside ``stream``). Each case runs in a fresh interpreter, since
this test process has torch loaded. These are import checks: the start-up times themselves are measured
with ``python -X importtime`` and ``/usr/bin/time`` (docs/experiments/2026-11-25-builtin-styles.md).
"""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

HEAVY = ("torch", "model.nets", "model.inference", "model.train", "service", "fastapi", "uvicorn", "matplotlib")
# The engine settings' declarations, which the output flags are built from, import nothing (their package's
# __init__ is a docstring).
LIGHT = ("model.inference", "model.inference.declared_settings")

PROBE = """
import json, sys
from rsmt_cli.main import main
try:
    code = main(sys.argv[1:])
except SystemExit as exc:
    code = exc.code
heavy = sorted(name for name, module in sys.modules.items() if module is not None and name not in LIGHT
               and any(name == h or name.startswith(h + ".") for h in HEAVY))
print(json.dumps({"code": code, "heavy": heavy}), file=sys.stderr)
"""


# Not needed to list styles or print the client's help: the other command groups, numpy, the WebSocket and
# async stacks, and httpx's own command-line tool (click, rich, pygments).
CLIENT_HEAVY = (*HEAVY, "model", "numpy", "websockets", "asyncio", "click", "rich", "pygments", "httpx._main",
                "rsmt_cli.data_commands", "rsmt_cli.loadtest_commands", "rsmt_cli.train_commands",
                "rsmt_cli.package_commands", "rsmt_client.stream", "rsmt_client.motion")


def _loaded(*argv: str, heavy: tuple[str, ...] = HEAVY) -> dict:
    result = subprocess.run([sys.executable, "-c", f"HEAVY = {heavy!r}\nLIGHT = {LIGHT!r}\n{PROBE}", *argv],
                            capture_output=True, text=True, timeout=120)
    return json.loads(result.stderr.strip().splitlines()[-1])


@pytest.mark.parametrize("argv", [
    ("--help",),
    ("train", "--help"),
    ("train", "all", "--help"),
    ("train", "classifier", "--help"),
    ("serve", "--help"),
    ("eval", "--help"),
    ("bench", "--help"),
    ("data", "inspect", "--help"),
    ("client", "styles", "list", "--help"),
])
def test_help_loads_no_heavy_module(argv):
    report = _loaded(*argv)
    assert report["code"] == 0
    assert report["heavy"] == []


def test_a_client_command_loads_no_heavy_module():
    # Nothing listens on port 9 of 127.0.0.1: the command fails fast with the client's error, having loaded the client only.
    report = _loaded("client", "styles", "list", "--url", "http://127.0.0.1:9", "--retries", "1", "--timeout", "2")
    assert report["code"] == 1
    assert report["heavy"] == []


@pytest.mark.parametrize("argv", [
    ("client", "--help"),
    ("client", "styles", "list", "--help"),
    ("client", "styles", "list", "--url", "http://127.0.0.1:9", "--retries", "1", "--timeout", "2"),
])
def test_a_client_command_loads_only_what_it_uses(argv):
    report = _loaded(*argv, heavy=CLIENT_HEAVY)
    assert report["code"] in (0, 1)  # 1: nothing listens on port 9
    assert report["heavy"] == []


def test_the_probe_sees_numpy_when_a_client_command_needs_it(tmp_path):
    # The check above can fail: reading a BVH (here a missing one, before any request) loads numpy.
    report = _loaded("client", "transition", "--context", str(tmp_path / "a.bvh"), "--target", str(tmp_path / "b.bvh"),
                     "--frames", "10", "--style", "builtin:normal", "--url", "http://127.0.0.1:9", "--retries", "1",
                     heavy=CLIENT_HEAVY)
    assert "numpy" in report["heavy"]


def test_the_command_table_names_what_each_group_registers():
    import argparse
    import importlib

    from rsmt_cli.main import GROUPS, build_parser

    def commands_of(parser: argparse.ArgumentParser) -> list[str]:
        subparsers = parser._subparsers
        assert subparsers is not None
        choices = subparsers._group_actions[0].choices
        assert choices is not None
        return list(choices)

    for module, commands in GROUPS:
        sub = argparse.ArgumentParser().add_subparsers()
        importlib.import_module(f"rsmt_cli.{module}").register(sub)
        assert tuple(sub.choices) == commands, module
    # A command line builds the parser of its own group only; no command: all of them, in the table's order.
    assert commands_of(build_parser([])) == [c for _, commands in GROUPS for c in commands]
    assert commands_of(build_parser(["-v", "client", "--help"])) == ["client"]


def test_the_probe_sees_torch_when_a_command_needs_it(tmp_path):
    # The check above can fail: a command that runs the model does load torch (and here fails on a missing bundle).
    report = _loaded("package", "--model", str(tmp_path / "missing"), "--out", str(tmp_path / "out"))
    assert "torch" in report["heavy"]


def test_the_classifier_choices_match_the_model():
    from model.nets.style_classifier import INPUTS
    from rsmt_cli.classifier_commands import INPUTS as CLI_INPUTS

    assert CLI_INPUTS == INPUTS
