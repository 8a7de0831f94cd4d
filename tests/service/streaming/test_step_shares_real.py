"""Per-key shares of the step budget through a real server (issue 53, item 7): with API keys on, a key with a
few asap characters keeps a share of the step time beside a key with many, instead of stepping in the big
key's batch at the big batch's pace. Each key's load runs in a process of its own (tests/service/key_load.py);
the rates are measured as the bench measures them (tests/service/step_share_bench.py)."""

from __future__ import annotations

import os
from collections.abc import Iterator

import pytest

from tests.service import step_share_bench
from tests.service.probes import GapProbe
from tests.service.server import Server

pytestmark = [pytest.mark.slow, pytest.mark.alone]  # two keys' asap characters on one server, twice

KEY_A, KEY_S = "step-share-key-a-0123456789abcdef", "step-share-key-s-0123456789abcdef"
SMALL, BIG, SECONDS = 2, 64, 4.0


@pytest.fixture(scope="module")
def server(bundle_dir) -> Iterator[Server]:
    env = {"RSMT_API_KEYS": f"{KEY_A},{KEY_S}", "RSMT_IDLE_TIMEOUT_S": "300"}
    if os.environ.get("RSMT_STEP_SHARES"):  # `off` shows what the test catches: one batch for every key
        env["RSMT_STEP_SHARES"] = os.environ["RSMT_STEP_SHARES"]
    srv = Server(bundle_dir, env=env).start()
    yield srv
    srv.stop()


def test_a_small_asap_key_keeps_its_share_of_the_steps_beside_a_big_one(server):
    with GapProbe(server.ws, characters=0, query=f"token={KEY_S}") as idle:
        frames = idle.frames
    rate_alone = step_share_bench.rate_alone(server, KEY_S, SMALL, frames, SECONDS)
    rate_small, rate_big = step_share_bench.rates_together(server, KEY_S, SMALL, KEY_A, BIG, frames, SECONDS)
    print(f"key S's {SMALL} asap characters: {rate_alone:.0f} frames/s alone, {rate_small:.0f} beside key A's {BIG} "
          f"({rate_big:.0f} frames/s): {rate_small / rate_alone:.2f} of its rate alone")
    assert rate_alone > 0 and rate_big > 0  # both keys move
    # Equal step time leaves S about half its rate alone (0.45 measured); in one batch with A's, S's
    # characters step at the big batch's pace, t(2 characters) / t(66 characters) of it (0.10 measured,
    # RSMT_STEP_SHARES=off).
    assert rate_small >= 0.25 * rate_alone
