"""``rsmt --help``, a command's ``--help`` and ``rsmt client ...`` start without torch, the model or the service.

Building the parser imports only argparse definitions; torch and the rest load inside the command
that needs them. Each case runs in a fresh interpreter, since this test process has torch loaded.
"""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

HEAVY = ("torch", "model.nets", "model.inference", "model.train", "service", "fastapi", "uvicorn", "matplotlib")

PROBE = """
import json, sys
from rsmt_cli.main import main
try:
    code = main(sys.argv[1:])
except SystemExit as exc:
    code = exc.code
heavy = sorted(name for name in sys.modules if any(name == h or name.startswith(h + ".") for h in HEAVY))
print(json.dumps({"code": code, "heavy": heavy}), file=sys.stderr)
"""


def _loaded(*argv: str) -> dict:
    result = subprocess.run([sys.executable, "-c", f"HEAVY = {HEAVY!r}\n{PROBE}", *argv],
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


def test_the_probe_sees_torch_when_a_command_needs_it(tmp_path):
    # The check above can fail: a command that runs the model does load torch (and here fails on a missing bundle).
    report = _loaded("package", "--model", str(tmp_path / "missing"), "--out", str(tmp_path / "out"))
    assert "torch" in report["heavy"]


def test_the_classifier_choices_match_the_model():
    from model.nets.style_classifier import INPUTS
    from rsmt_cli.classifier_commands import INPUTS as CLI_INPUTS

    assert CLI_INPUTS == INPUTS
