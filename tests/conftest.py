"""Shared fixtures: the real motion data (skipped with a reason when absent)."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from model.data.location import ENV_VAR, find_data_dir

pytest_plugins = ["tests.run_alone"]  # tests marked `alone` run with no other worker's test beside them


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """The folder of real BVH takes; tests using it skip when it is not there."""
    path = find_data_dir()
    if path is None:
        pytest.skip(
            f"real motion data not found: set {ENV_VAR} to the unpacked Bandai-Namco folder "
            "(../shared/data/unpack.sh prints it)"
        )
    return path


@pytest.fixture(scope="session")
def default_model_eager_server():
    """One server of the default model, eager and warmed at batch 1 (quick to start), for the session's tests that
    use it as a user would (tests/service/test_docs_examples.py, tests/viewer/test_viewer_default_model.py):
    one start instead of one a module."""
    from model.inference.bundle import DEFAULT_BUNDLE
    from tests.service.server import Server

    srv = Server(DEFAULT_BUNDLE, env={"RSMT_WARMUP_MAX_BATCH": "1", "RSMT_EAGER": "true"}).start(300)
    yield srv
    srv.stop()


@pytest.fixture(scope="session")
def default_onnx_export(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``rsmt export onnx`` of the default bundle, once a session: the graphs and sidecar that the export's tests
    (tests/model/export/test_onnx_export.py) check and the engine samples (tests/clients/test_engine_samples.py) run."""
    from rsmt_cli.main import main

    out = tmp_path_factory.mktemp("onnx")
    assert main(["export", "onnx", "--out", str(out)]) == 0
    return out


@pytest.fixture
def one_thread():
    """Run a test on one torch thread: many small tensor ops are faster that way on 2 cores."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


# The slow tier (`python -m pytest -m "not slow"` leaves it out): besides the tests marked slow in their
# files, every test on the real motion data and every test needing one of these fixtures.
SLOW_FIXTURES = {
    "harness_exe": "compiles the Unity core with Mono's mcs",
    "core_test_exe": "compiles the Unreal core with g++",
    "failover_exe": "compiles the Unreal failover harness with g++",
    "browser": "drives headless chromium",
    "redis_server": "starts a redis-server",
}


@pytest.hookimpl(tryfirst=True)  # before -m selects by mark
def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    for item in items:
        if item.get_closest_marker("real_data") or SLOW_FIXTURES.keys() & set(getattr(item, "fixturenames", ())):
            item.add_marker(pytest.mark.slow)
