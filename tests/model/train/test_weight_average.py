"""Weight averaging of bundles: the mean is taken weight by weight, the endpoints are the inputs,
and bundles that do not share a shape are refused."""

from __future__ import annotations

import json

import pytest
import torch

from model.inference.bundle import Bundle, BundleError
from model.inference.output.settings import OutputConfig
from model.nets.sampler import SamplerConfig
from model.train.weight_average import average_bundles
from rsmt_cli.main import main
from tests.model.tiny_bundles import SAMPLER
from tests.model.tiny_bundles import tiny_bundle as _bundle


def _floats(bundle: Bundle) -> dict[str, torch.Tensor]:
    return {k: v for k, v in bundle.tensors().items() if v.is_floating_point()}


def test_weights_are_mixed_one_by_one_and_the_endpoints_are_the_inputs():
    a, b = _bundle(1), _bundle(2)
    a.output = OutputConfig(smoothing=0.3)
    fa, fb = _floats(a), _floats(b)
    assert any(not torch.equal(fa[k], fb[k]) for k in fa)  # two different models
    mixed = _floats(average_bundles([a, b], [0.25, 0.75]))
    for k in fa:
        assert torch.allclose(mixed[k], 0.25 * fa[k] + 0.75 * fb[k], atol=1e-6), k
    only_a = _floats(average_bundles([a, b], [1.0, 0.0]))
    assert all(torch.equal(only_a[k], fa[k]) for k in fa)
    # Weights are normalised; equal weights by default.
    assert all(torch.allclose(x, y) for x, y in zip(_floats(average_bundles([a, b], [2, 2])).values(),
                                                    _floats(average_bundles([a, b])).values()))
    out = average_bundles([a, b], [1, 3], name="soup")
    assert out.output == a.output and out.meta.name == "soup"
    assert "x 0.25" in out.meta.notes and "x 0.75" in out.meta.notes
    assert _floats(a).keys() == fa.keys() and all(torch.equal(_floats(a)[k], fa[k]) for k in fa)  # inputs untouched


def test_bundles_of_another_shape_and_bad_weights_are_refused():
    a = _bundle(1)
    wider = SamplerConfig(**{**SAMPLER.to_dict(), "width": 48})
    with pytest.raises(BundleError, match="sampler config"):
        average_bundles([a, _bundle(2, wider)])
    for weights, message in (([1.0], "2 bundles"), ([-1.0, 2.0], "0 or more"), ([0.0, 0.0], "not all 0"),
                             ([float("nan"), 1.0], "0 or more")):
        with pytest.raises(ValueError, match=message):
            average_bundles([a, _bundle(2)], weights)
    with pytest.raises(ValueError, match="at least two"):
        average_bundles([a])


@pytest.mark.slow  # trains two bundles
def test_rsmt_average_writes_a_loadable_bundle(tmp_path, capsys):
    _bundle(1).save(tmp_path / "a")
    _bundle(2).save(tmp_path / "b")
    args = ["average", "--model", str(tmp_path / "a"), "--model", str(tmp_path / "b"), "--weight", "0.3",
            "--weight", "0.7", "--float16", "--out", str(tmp_path / "c")]
    assert main(args) == 0
    report = json.loads(capsys.readouterr().out)
    c = Bundle.load(tmp_path / "c")
    assert report["version"] == c.version
    expect = {k: 0.3 * v + 0.7 * _floats(Bundle.load(tmp_path / "b"))[k]
              for k, v in _floats(Bundle.load(tmp_path / "a")).items()}
    assert all(torch.allclose(_floats(c)[k], v, atol=2e-3, rtol=2e-3) for k, v in expect.items())  # float16 storage
    # Writing over one of the inputs is refused before anything is written.
    assert main(args[:-1] + [str(tmp_path / "a")]) == 2
    assert "must not be one of" in capsys.readouterr().err
