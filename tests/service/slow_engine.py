"""``python -m tests.service.slow_engine serve ...``: the ``rsmt`` command with every whole transition
slowed by ``RSMT_TEST_GENERATE_DELAY_S`` seconds (a sleep before its first step,
``service.transition_steps.TransitionSteps``: it holds a work thread without using CPU), so that a test can
fill a model's work queue with a few requests on a small machine. Everything else is the real command:
``rsmt serve`` under uvicorn with its signals, drain and graceful shutdown."""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path
from typing import Any

from service.transition_steps import TransitionSteps
from tests.service.server import Server

DELAY_ENV = "RSMT_TEST_GENERATE_DELAY_S"


def slow_server(bundle: Path, delay_s: float, queue_limit: int, env: dict[str, str] | None = None) -> Server:
    """A (not yet started) real ``rsmt serve`` through this module: one work thread, each transition held
    ``delay_s`` seconds, at most ``queue_limit`` requests waiting; ``env`` adds settings."""
    return Server(bundle, command=[sys.executable, "-m", "tests.service.slow_engine", "serve", "--host", "127.0.0.1",
                                   "--port", "{port}"],
                  env={DELAY_ENV: str(delay_s), "RSMT_QUEUE_LIMIT": str(queue_limit), "RSMT_REQUEST_THREADS": "1",
                       **(env or {})})


def install(delay_s: float) -> None:
    original = TransitionSteps.__init__

    def init(self: TransitionSteps, *args: Any, **kwargs: Any) -> None:
        time.sleep(delay_s)
        original(self, *args, **kwargs)

    TransitionSteps.__init__ = init  # type: ignore[method-assign]


if __name__ == "__main__":
    install(float(os.environ.get(DELAY_ENV, "0")))
    from rsmt_cli.main import main

    sys.exit(main())
