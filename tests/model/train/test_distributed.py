"""Training on several processes: gradients averaged over the ranks, and ``rsmt train`` under torchrun."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch
import torch.distributed as dist
import torch.multiprocessing as mp
from safetensors.torch import load_file, save_file
from torch import nn

from model.train import distributed
from model.train.loop import LoopConfig, step_generator, train_loop

pytestmark = [pytest.mark.slow, pytest.mark.usefixtures("one_thread")]  # slow: starts process groups (torch.distributed)

WORLD = 2


class Toy(nn.Module):
    """A linear model, a parameter only rank 1's step reaches, and one no step reaches."""

    def __init__(self) -> None:
        super().__init__()
        self.linear = nn.Linear(3, 2)
        self.extra = nn.Parameter(torch.ones(2))
        self.unused = nn.Parameter(torch.ones(2))


def _toy_data() -> tuple[torch.Tensor, torch.Tensor]:
    gen = torch.Generator().manual_seed(7)
    return torch.randn(8, 3, generator=gen), torch.randn(8, 2, generator=gen)


def _toy_model() -> Toy:
    torch.manual_seed(3)
    return Toy()


def _worker(rank: int, folder: str) -> None:
    """One rank of a gloo group on the CPU: one averaged step, then a short train_loop (results written to ``folder``)."""
    torch.set_num_threads(1)
    dist.init_process_group("gloo", init_method=f"file://{folder}/rendezvous", rank=rank, world_size=WORLD)
    try:
        _averaged_step(rank, folder)
        _short_loop(rank, folder)
    finally:
        dist.destroy_process_group()


@pytest.fixture(scope="module")
def two_ranks(tmp_path_factory) -> Path:
    """The folder of what two spawned processes wrote (spawned once: starting them is the slow part)."""
    folder = tmp_path_factory.mktemp("ranks")
    mp.spawn(_worker, args=(str(folder),), nprocs=WORLD, join=True)
    return folder


def _averaged_step(rank: int, folder: str) -> None:
    model = _toy_model()
    x, y = _toy_data()
    rows = slice(rank * 4, rank * 4 + 4)  # each rank its half of the batch
    loss = nn.functional.mse_loss(model.linear(x[rows]), y[rows])
    if rank == 1:
        loss = loss + (model.extra ** 2).sum()
    loss.backward()
    distributed.average_gradients(model.parameters())
    assert model.unused.grad is None
    torch.optim.SGD(model.parameters(), lr=0.1).step()
    save_file({k: v.contiguous() for k, v in model.state_dict().items()}, f"{folder}/rank{rank}.safetensors")


def test_average_gradients_matches_one_process_on_the_whole_batch(two_ranks):
    """After one step on half a batch each, both ranks hold the weights one process gets from the whole batch."""
    model = _toy_model()
    x, y = _toy_data()
    # The mean over both halves; the parameter only rank 1 reached counts as zero on rank 0.
    loss = nn.functional.mse_loss(model.linear(x), y) + 0.5 * (model.extra ** 2).sum()
    loss.backward()
    torch.optim.SGD(model.parameters(), lr=0.1).step()
    expected = model.state_dict()
    ranks = [load_file(str(two_ranks / f"rank{r}.safetensors")) for r in range(WORLD)]
    for name, value in expected.items():
        assert torch.equal(ranks[0][name], ranks[1][name]), name
        torch.testing.assert_close(ranks[0][name], value, rtol=1e-6, atol=1e-7)
    assert not torch.equal(ranks[0]["linear.weight"], _toy_model().linear.weight.detach())  # it did train
    assert torch.equal(ranks[0]["unused"], torch.ones(2))  # no rank reached it: untouched, as in one process


def _short_loop(rank: int, folder: str) -> None:
    model = _toy_model()
    x, y = _toy_data()
    draws: list[list[int]] = []
    noise: list[float] = []

    def step(i: int) -> dict[str, float]:
        rows = torch.randint(len(x), (4,), generator=step_generator(0, i))
        draws.append(rows.tolist())
        noise.append(float(torch.randn(1)))  # the global RNG: each rank its own stream too
        loss = nn.functional.mse_loss(model.linear(x[rows]) + noise[-1], y[rows])
        loss.backward()
        return {"mse": loss.item()}

    cfg = LoopConfig(iterations=5, epoch_iterations=5, lr=1e-2, warmup=1)
    params = [(n, p) for n, p in model.named_parameters() if n.startswith("linear.")]
    result = train_loop("toy", Path(folder) / "run", model, params, cfg, step, lambda: {}, progress=False)
    assert result.finished
    save_file({k: v.contiguous() for k, v in model.state_dict().items()}, f"{folder}/loop{rank}.safetensors")
    (Path(folder) / f"draws{rank}.json").write_text(json.dumps({"rows": draws, "noise": noise}))


def test_train_loop_ranks_draw_apart_and_stay_in_step(two_ranks):
    """Under a process group each rank draws its own batches and noise, yet every rank ends with the same
    weights; rank 0 alone writes the checkpoint, and its batches are those one process draws."""
    tmp_path = two_ranks
    draws = [json.loads((tmp_path / f"draws{r}.json").read_text()) for r in range(WORLD)]
    assert draws[0]["rows"] != draws[1]["rows"] and draws[0]["noise"] != draws[1]["noise"]
    assert draws[0]["rows"] == [torch.randint(8, (4,), generator=step_generator(0, i)).tolist() for i in range(5)]
    weights = [load_file(str(tmp_path / f"loop{r}.safetensors")) for r in range(WORLD)]
    for name in weights[0]:
        assert torch.equal(weights[0][name], weights[1][name]), name
    checkpoint = load_file(str(tmp_path / "run" / "checkpoint.safetensors"))
    assert torch.equal(checkpoint["model.linear.weight"], weights[0]["linear.weight"])
    assert json.loads((tmp_path / "run" / "checkpoint.json").read_text())["step"] == 5


def test_one_process_is_not_distributed():
    assert not distributed.active() and distributed.world_size() == 1 and distributed.is_main()
    assert distributed.step_seed(3, 5) == 3 * 1_000_003 + 5  # the stream every single-process run draws


def _torchrun(tmp_path: Path, data: Path) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "RSMT_CACHE": str(tmp_path / "cache"), "OMP_NUM_THREADS": "1"}
    for var in ("WORLD_SIZE", "RANK", "LOCAL_RANK", "MASTER_ADDR", "MASTER_PORT"):
        env.pop(var, None)
    # torchrun's own parser reads --run as an ambiguous --run-path: the run folder is given as --run-dir.
    command = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node", str(WORLD),
               "-m", "rsmt_cli", "train", "all", "--preset", "smoke", "--data", str(data), "--run-dir",
               str(tmp_path / "run"), "--out", str(tmp_path / "bundle"), "--threads", "1", "--device", "cpu", "--quiet"]
    return subprocess.run(command, env=env, capture_output=True, text=True, timeout=300)


@pytest.mark.slow
def test_rsmt_train_all_under_torchrun_on_two_cpu_processes(tmp_path):
    from model.data.synthetic import write_synthetic_dataset
    from model.inference.bundle import Bundle

    data = tmp_path / "data"
    write_synthetic_dataset(data)
    done = _torchrun(tmp_path, data)
    assert done.returncode == 0, done.stderr[-4000:]
    for rank in range(WORLD):  # every process trained every stage to its end
        assert f"process {rank} of {WORLD}: trained phase, manifold, sampler" in done.stderr
    summary = json.loads(done.stdout[done.stdout.index("{"):])  # printed once, by rank 0
    assert summary["bundle"] == str(tmp_path / "bundle") and summary["timings_s"]["processes"] == WORLD
    bundle = Bundle.load(tmp_path / "bundle")
    assert bundle.meta.name == "rsmt-smoke" and bundle.meta.training_time_s["processes"] == WORLD
    config = json.loads((tmp_path / "run" / "train_config.json").read_text())
    for stage in ("phase", "manifold", "sampler"):  # rank 0's checkpoints, at each stage's last step
        meta = json.loads((tmp_path / "run" / stage / "checkpoint.json").read_text())
        assert meta["step"] == config[f"{stage}_stage"]["loop"]["iterations"]
    # Run again: every rank loads the finished checkpoints and the same bundle is written.
    again = _torchrun(tmp_path, data)
    assert again.returncode == 0, again.stderr[-4000:]
    assert Bundle.load(tmp_path / "bundle").version == bundle.version
