"""The speed bench runs and reports every figure (numbers are machine-dependent, never asserted)."""

from __future__ import annotations

from typing import cast

import pytest

from model.bench import BenchResult, bench_engine, format_table, machine_probe, paired_latency, per_frame_parameters
from model.data.synthetic import synthetic_skeleton
from model.inference.bundle import Bundle
from model.inference.engine import Engine
from model.inference.overrides import Overrides
from model.inference.traced_step import CompiledStep
from model.nets.manifold import ManifoldConfig
from model.nets.sampler import SamplerConfig


def test_bench_smoke():
    cfg = SamplerConfig(joints=21, phases=4, latent=8, width=32, rnn=32, head=32, style_channels=32, max_transition=20)
    man = ManifoldConfig(joints=21, phases=4, latent=8, experts=2, hidden=32, gate_hidden=16, encoder_hidden=32)
    bundle = Bundle.create(synthetic_skeleton(), cfg, man)
    res = bench_engine(Engine(bundle), "tiny", batch_sizes=(1, 4), latency_frames=30, budget_s=0.5)
    assert isinstance(res, BenchResult)
    assert res.latency_ms["median"] > 0 and res.latency_ms["p99"] >= res.latency_ms["median"]
    assert set(res.throughput) == {1, 4} and all(v > 0 for v in res.throughput.values())
    assert res.style_encode_ms > 0 and res.rss_mb > 0
    assert 0 < per_frame_parameters(bundle) < sum(p.numel() for p in bundle.sampler.parameters())
    probe = machine_probe(seconds=0.2)
    table = format_table([res], probe)
    assert "| tiny |" in table and "GFLOP/s" in table


def test_bench_refuses_an_output_strength_out_of_range_naming_the_flag(capsys):
    from rsmt_cli.main import main

    assert main(["bench", "--no-paper", "--root-smoothing", "1.0"]) == 2
    assert "--root-smoothing must be in [0, 1)" in capsys.readouterr().err


def test_paired_latency_takes_turns_and_reports_both_medians_and_their_ratio():
    cfg = SamplerConfig(joints=21, phases=4, latent=8, width=32, rnn=32, head=32, style_channels=32, max_transition=20)
    man = ManifoldConfig(joints=21, phases=4, latent=8, experts=2, hidden=32, gate_hidden=16, encoder_hidden=32)
    small = Engine(Bundle.create(synthetic_skeleton(), cfg, man))
    big_cfg = SamplerConfig(joints=21, phases=4, latent=8, width=256, rnn=512, head=256, style_channels=32, max_transition=20)
    big = Engine(Bundle.create(synthetic_skeleton(), big_cfg, man))
    calls: list[str] = []
    for name, engine in (("small", small), ("big", big)):
        step = engine.weight_sets[""].step_fn

        def counted(*args, _step=step, _name=name):
            calls.append(_name)
            return _step(*args)

        # A counting stand-in for the compiled step (it calls the real one): cast, as it is no CompiledStep.
        engine.weight_sets[""].step_fn = cast(CompiledStep, counted)
    paired = paired_latency(small, big, blocks=4, frames=6, warm=1)
    assert paired.first_ms > 0 and paired.second_ms > 0 and paired.ratio == paired.first_ms / paired.second_ms
    # One step a timed or warm frame; the engines take turns a block at a time, the first alternating.
    s, b = ["small"] * 7, ["big"] * 7
    assert calls == s + b + b + s + s + b + b + s
    assert paired.to_dict()["blocks"] == 4 and paired.to_dict()["frames_per_block"] == 6


def test_the_memory_floor_counts_the_bytes_each_backend_reads():
    from model.bench import weight_bytes_per_frame

    cfg = SamplerConfig(joints=21, phases=4, latent=8, width=32, rnn=64, head=32, style_channels=32, max_transition=20)
    man = ManifoldConfig(joints=21, phases=4, latent=8, experts=2, hidden=32, gate_hidden=16, encoder_hidden=32)
    bundle = Bundle.create(synthetic_skeleton(), cfg, man)
    float32 = weight_bytes_per_frame(Engine(bundle, overrides=Overrides(int8_lstm=False)))
    assert float32 == 4 * per_frame_parameters(bundle)
    lstm = bundle.sampler.lstm.weight_ih.numel() + bundle.sampler.lstm.weight_hh.numel()
    int8 = Engine(bundle, overrides=Overrides(int8_lstm=True))
    assert weight_bytes_per_frame(int8) == float32 - 3 * lstm  # the int8 matrices at one byte
    res = BenchResult("tiny", per_frame_parameters(bundle), latency_ms={"median": 1.0, "p99": 1.0}, bytes_per_frame=float32)
    assert abs(res.floor_ms({"memcpy_gbps": 10.0, "matmul_gflops": 1.0}) - float32 / 1e10 * 1e3) < 1e-12
    assert "memory floor ms" in format_table([res], {"memcpy_gbps": 10.0, "matmul_gflops": 1.0})


def test_the_bench_times_frames_by_the_clock_it_is_given():
    cfg = SamplerConfig(joints=21, phases=4, latent=8, width=32, rnn=32, head=32, style_channels=32, max_transition=20)
    man = ManifoldConfig(joints=21, phases=4, latent=8, experts=2, hidden=32, gate_hidden=16, encoder_hidden=32)
    engine = Engine(Bundle.create(synthetic_skeleton(), cfg, man))
    ticks = iter(range(10**9))

    def clock() -> float:  # a clock a millisecond on at every reading: every timed span reads 1 ms
        return next(ticks) / 1000

    res = bench_engine(engine, "tiny", batch_sizes=(1,), latency_frames=20, budget_s=0.5, clock=clock)
    assert res.latency_ms == {"median": 1.0, "p99": 1.0, "mean": 1.0} and res.style_encode_ms == 1.0
    paired = paired_latency(engine, engine, blocks=2, frames=3, warm=1, clock=clock)
    assert paired.first_ms == paired.second_ms == 1.0


@pytest.mark.slow  # benches the default bundle
def test_bench_cli_times_by_cpu_time_on_request(tmp_path, capsys):
    import json

    from rsmt_cli.main import main

    out = tmp_path / "bench.json"
    assert main(["bench", "--no-paper", "--clock", "cpu", "--batch-sizes", "1", "--budget", "0.2", "--json", str(out)]) == 0
    assert "CPU time (--clock cpu)" in capsys.readouterr().out
    report = json.loads(out.read_text())
    assert report["clock"] == "cpu" and report["results"][0]["latency_ms"]["median"] > 0
