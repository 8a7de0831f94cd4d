"""``rsmt loadtest`` briefly against real servers on 127.0.0.1: the shared client-test server (streaming), and one
it spawns itself (POST /v1/transition); the printed figures must add up."""

from __future__ import annotations

import json

import httpx
import pytest

from rsmt_cli.main import main as rsmt_main
from tests.clients.helpers import API_KEY

pytestmark = pytest.mark.slow  # load tests against spawned servers

CHARACTERS, PER_CONNECTION, FRAMES = 5, 2, 12


def test_streaming_figures(server, tmp_path, capsys):
    out = tmp_path / "load.json"
    code = rsmt_main(["loadtest", "--url", server.url, "--api-key", API_KEY, "--characters", str(CHARACTERS),
                      "--per-connection", str(PER_CONNECTION), "--frames", str(FRAMES), "--seconds", "30",
                      "--max-transitions", "1", "--soak", "--sample-s", "0.2", "--progress-s", "0.2", "--json", str(out)])
    printed = capsys.readouterr()
    assert code == 0, printed.err
    figures = json.loads(printed.out)
    assert figures == json.loads(out.read_text())
    # One transition per character (--max-transitions 1), every frame of each, in order and none missing.
    assert figures["transitions"] == CHARACTERS and figures["transition_frames"] == FRAMES
    assert figures["frames_received"] == CHARACTERS * FRAMES
    assert figures["dropped_frames"] == 0 and figures["errors"] == [] and figures["error_count"] == 0
    assert figures["latency_ms"]["n"] == CHARACTERS * FRAMES and figures["gap_ms"]["n"] == CHARACTERS * (FRAMES - 1)
    assert figures["start_latency_ms"]["n"] == CHARACTERS and figures["start_latency_ms"]["p50"] > 0
    # Realtime pacing: frames of a character arrive about one frame period apart; the run lasts about one transition.
    period_ms = 1e3 / figures["fps"]
    assert 0.3 * period_ms < figures["gap_ms"]["p50"] < 3 * period_ms
    assert figures["wall_s"] < 25 and 0 < figures["throughput_fps"] <= figures["target_fps"] * 1.5
    assert 0 <= figures["late_frames"] <= figures["frames_received"]
    # The server's side, from /metrics: it sent at least these frames and spent CPU on them.
    assert figures["server_cpu_ms_per_frame"] > 0 and figures["engine_step_wall_ms_per_frame"] > 0
    assert figures["prepare_ms_per_start"] > 0 and figures["mean_batch"] >= 1
    assert figures["rss_mib"] and all(mib > 10 for _, mib in figures["rss_mib"])
    assert "rsmt loadtest:" in printed.err and "frames (" in printed.err  # progress lines


def test_spawned_server_and_transition_requests(client_bundle, tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("RSMT_WARMUP_MAX_BATCH", "1")
    monkeypatch.setenv("RSMT_LOG_LEVEL", "warning")
    code = rsmt_main(["loadtest", "--spawn", "--bundle", str(client_bundle), "--transition", "3", "--frames", "10",
                      "--progress-s", "0"])
    printed = capsys.readouterr()
    assert code == 0, printed.err
    figures = json.loads(printed.out)
    assert figures["requests"] == 3 and figures["frames"] == 10
    for key in ("client_ms", "server_total_ms", "server_engine_ms", "in_process_engine_ms"):
        assert figures[key]["n"] == 3 and figures[key]["p50"] > 0, key
    assert figures["client_ms"]["p50"] >= figures["server_total_ms"]["p50"] >= figures["server_engine_ms"]["p50"]
    assert printed.err == ""  # --progress-s 0: quiet
    # The spawned server is gone once the command returns.
    with pytest.raises(httpx.ConnectError):
        httpx.get(figures["url"] + "/v1/health/live", timeout=2)


def test_needs_a_server(capsys):
    with pytest.raises(SystemExit) as exit_:
        rsmt_main(["loadtest", "--characters", "2"])
    assert exit_.value.code == 2 and "--url" in capsys.readouterr().err
    assert rsmt_main(["loadtest", "--url", "http://127.0.0.1:9", "--characters", "1", "--seconds", "1"]) == 1
    assert "cannot reach" in capsys.readouterr().err
