"""A command whose reader goes away (``rsmt client demo | head -5``) ends quietly, as a command killed by SIGPIPE:
exit status 141 and no traceback (issue 64: it ended in a BrokenPipeError traceback)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from model.data.synthetic import synthetic_walk
from model.motion.bvh_clip import dump_clip
from rsmt_cli.main import EXIT_BROKEN_PIPE


def test_output_to_a_closed_pipe_ends_quietly(tmp_path: Path) -> None:
    take = tmp_path / "walk.bvh"
    take.write_text(dump_clip(synthetic_walk(30)))
    read_end, write_end = os.pipe()
    os.close(read_end)  # the reader is gone before the command writes: every write to stdout fails with EPIPE
    try:
        done = subprocess.run([sys.executable, "-m", "rsmt_cli", "profile", "guess", str(take)], stdout=write_end,
                              stderr=subprocess.PIPE, text=True, timeout=120)
    finally:
        os.close(write_end)
    assert done.returncode == EXIT_BROKEN_PIPE, done.stderr[-2000:]
    assert "Traceback" not in done.stderr and "BrokenPipeError" not in done.stderr, done.stderr[-2000:]
    assert done.stderr.startswith("profile guessed from")  # the command ran; only its printed profile was lost
