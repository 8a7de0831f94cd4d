"""A load script of the tests run as a child process (``python -m ...`` from the repository root) that prints
``ready`` once it runs, inside a ``with`` block that kills it if it is still running at the end."""

from __future__ import annotations

import subprocess
from pathlib import Path
from typing import Any, Self


class ChildRun:
    """Subclasses set ``command`` (the child's argv) and ``not_started`` (the error's words when the child says
    anything but ``ready`` first, or dies)."""

    command: list[str]
    not_started = "the child process did not start"
    proc: subprocess.Popen[str] | None = None

    def __enter__(self) -> Self:
        self.proc = subprocess.Popen(self.command, stdout=subprocess.PIPE, text=True,
                                     cwd=Path(__file__).resolve().parents[2])
        assert self.proc.stdout is not None
        line = self.proc.stdout.readline()  # "ready", or "" if it died
        if line.strip() != "ready":
            self.proc.kill()
            raise RuntimeError(f"{self.not_started}: {line!r}")
        return self

    def __exit__(self, *exc: Any) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(10)
