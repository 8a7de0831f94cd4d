"""Style adapters: a fine-tuned style's weights beside the bundle's own. The other styles run on the bundle's
weights unchanged to the bit, the adapted style on its own, in one batch; adapters that do not fit are refused."""

from __future__ import annotations

import copy
import hashlib
import json
import shutil

import pytest
import torch

from model.inference.bundle import Bundle, BundleError
from model.inference.bundle_adapters import AdapterError, adapter_from
from model.inference.bundle_styles import StyleClip, StyleFolderError
from model.inference.engine import CharacterBatch, Engine
from model.inference.style_packing import write_adapter, write_builtin_styles
from model.nets.sampler import SamplerState, TransitionSampler
from tests.model.tiny_bundles import tiny_bundle

pytestmark = pytest.mark.usefixtures("one_thread")


def _tuned(sampler: TransitionSampler, seed: int = 3) -> TransitionSampler:
    """The sampler with its FiLM, LSTM and head weights moved, as a network-scope fine-tuning would. Moved by
    0.1 of a unit normal: at 0.2 the untrained recurrence is chaotic enough that float rounding (which a
    batch's size and make-up change) grew to 0.01 in 12 frames on an AVX2 machine, and "the same frames
    as alone" could not be told from "other frames"."""
    tuned = copy.deepcopy(sampler)
    gen = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for name, p in tuned.named_parameters():
            if name.startswith(("film1.", "lstm.", "head_out.", "style_encoder.")):
                p.add_(0.1 * torch.randn(p.shape, generator=gen))
    return tuned


@pytest.fixture()
def adapted(tmp_path, walk):
    """A float16 bundle with the built-in style ``slow``, and the same bundle plus the adapter ``limp``."""
    base = tmp_path / "base"
    tiny_bundle(1).save(base, weights_dtype="float16")
    write_builtin_styles(base, [StyleClip("slow", walk.window(0, 60), "slow.bvh")])
    loaded = Bundle.load(base)
    tuned = _tuned(loaded.sampler)
    adapter = adapter_from(loaded.sampler, tuned, "limp", loaded.version, "test")
    out = tmp_path / "adapted"
    shutil.copytree(base, out)
    write_adapter(out, adapter, StyleClip("limp", walk.window(20, 100), "limp.bvh"))
    return base, out, tuned


def _files(folder) -> dict[str, str]:
    return {p.relative_to(folder).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def test_the_adapter_holds_the_changed_tensors_alone_and_the_bundle_is_left_as_it_was(adapted):
    base, out, tuned = adapted
    before, after = _files(base), _files(out)
    assert {k: v for k, v in after.items() if not k.startswith("adapters/")} == before  # byte for byte
    bundle = Bundle.load(out)
    adapter = bundle.adapters["limp"]
    assert adapter.tensors and all(k.startswith(("film1.", "lstm.", "head_out.", "style_encoder.")) for k in adapter.tensors)
    assert not any(k.startswith("decoder.") for k in adapter.tensors)
    assert bundle.styles["slow"].weights == "" and bundle.styles["limp"].weights == "limp"
    assert bundle.styles["limp"].version == adapter.version != bundle.version
    applied = adapter.apply(bundle.sampler).state_dict()
    assert all(torch.equal(v, tuned.state_dict()[k]) for k, v in applied.items())
    meta = json.loads((out / "adapters" / "limp" / "adapter.json").read_text())
    assert meta["base_version"] == bundle.version and meta["notes"] == "test"


def _chars(engine, walk, styles, frames=12):
    return [engine.prepare(walk.window(i, i + 10), walk.window(i + 30, i + 31), frames, s, seed=i)
            for i, s in enumerate(styles)]


def test_other_styles_run_on_the_bundles_weights_unchanged_and_the_new_one_on_its_own(adapted, walk):
    base, out, tuned = adapted
    plain, engine = Engine(Bundle.load(base)), Engine(Bundle.load(out))
    assert sorted(engine.weight_sets) == ["", "limp"]
    slow_plain = plain.encode_style(walk.window(0, 60))[0]
    slow = engine.encode_style(walk.window(0, 60))[0]
    limp = engine.encode_style(walk.window(20, 100), weights="limp")[0]
    assert slow.weights == "" and limp.weights == "limp" and limp.style_id != slow.style_id
    # Known styles: the same frames to the bit as the bundle before the adapter.
    known = engine.generate(_chars(engine, walk, [slow, slow]))
    for (r, p), (r0, p0) in zip(known, plain.generate(_chars(plain, walk, [slow_plain, slow_plain]))):
        assert torch.equal(r, r0) and torch.equal(p, p0)
    # A batch mixing both weight sets gives each character what its own weights give alone.
    mixed = engine.generate(_chars(engine, walk, [slow, limp, slow, limp]))
    alone = Bundle.load(out)
    alone.sampler = tuned.eval()
    own = Engine(alone)
    limp_own = own.encode_style(walk.window(20, 100))[0]
    assert torch.allclose(limp_own.context.keys1, limp.context.keys1, atol=1e-6)
    expected = (plain.generate(_chars(plain, walk, [slow_plain]))[0], own.generate(_chars(own, walk, [limp_own] * 2))[1])
    for i in (0, 1):
        rot, root = mixed[i]
        assert torch.allclose(rot, expected[i][0], atol=1e-4) and torch.allclose(root, expected[i][1], atol=1e-3)
    assert not torch.allclose(mixed[0][0], mixed[1][0], atol=1e-2)


def test_a_style_switch_to_other_weights_reencodes_the_target(adapted, walk):
    _, out, _ = adapted
    engine = Engine(Bundle.load(out))
    slow = engine.encode_style(walk.window(0, 60))[0]
    limp = engine.encode_style(walk.window(20, 100), weights="limp")[0]
    batch = CharacterBatch(engine)
    ch = _chars(engine, walk, [slow])[0]
    batch.add(ch)
    batch.step()
    row = batch.row_of(ch)
    engine.set_style(ch, limp, batch)
    limp_net, now = engine.weights("limp").net, batch.row_of(ch)
    assert isinstance(row, SamplerState) and isinstance(now, SamplerState) and isinstance(limp_net, TransitionSampler)
    assert torch.allclose(now.target_emb, limp_net.target_encoder(row.target_vec)) and ch.style is limp
    while not ch.done:
        batch.step()
    # Out of a batch (a parked stream), the row it holds is re-encoded the same way.
    ch2 = _chars(engine, walk, [limp])[0]
    parking = CharacterBatch(engine)
    parking.add(ch2)
    parking.step()
    parking.detach(ch2)  # its row handed back, as a stream parked for a full queue holds it
    assert ch2.parked is not None
    before = ch2.parked
    engine.set_style(ch2, slow)
    held = ch2.parked.row if ch2.parked is not None else None
    assert isinstance(held, SamplerState) and ch2.parked is not before
    assert torch.allclose(held.target_emb, engine.bundle.sampler.target_encoder(held.target_vec))
    with pytest.raises(ValueError, match="no weights 'gone'"):
        engine.weights("gone")


def test_adapters_that_do_not_fit_are_refused(adapted, walk, tmp_path):
    base, out, tuned = adapted
    # A style of the same name as an adapter, in either place.
    with pytest.raises(StyleFolderError, match="weights of their own"):
        write_builtin_styles(out, [StyleClip("limp", walk.window(0, 60), "x.bvh")])
    loaded = Bundle.load(out)
    with pytest.raises(StyleFolderError, match="already has a built-in style 'slow'"):
        write_adapter(out, adapter_from(loaded.sampler, tuned, "slow", loaded.version), StyleClip("slow", walk, ""))
    # Tuned from other weights.
    other = tmp_path / "other"
    tiny_bundle(2).save(other)
    shutil.copytree(out / "adapters", other / "adapters")
    with pytest.raises(BundleError, match="tuned from model version"):
        Bundle.load(other)
    # Weights that are not the ones adapter.json names.
    path = out / "adapters" / "limp" / "weights.safetensors"
    from safetensors.torch import load_file, save_file

    tensors = load_file(str(path))
    key = next(iter(tensors))
    tensors[key] = tensors[key] + 1
    save_file(tensors, str(path), metadata={"format": "rsmt-adapter/1"})
    with pytest.raises(BundleError, match="not the ones adapter.json names"):
        Bundle.load(out)
    with pytest.raises(AdapterError, match="changed no weight"):
        adapter_from(loaded.sampler, loaded.sampler, "same", loaded.version)


def test_a_blended_adapter_lies_between_the_bundle_and_the_tuned_weights(adapted):
    _, out, tuned = adapted
    base = Bundle.load(out).sampler
    full = adapter_from(base, tuned, "x", "v")
    half = adapter_from(base, tuned, "x", "v", blend=0.5)
    own = base.state_dict()
    assert full.tensors.keys() == half.tensors.keys()
    for k, t in half.tensors.items():
        assert torch.equal(full.tensors[k], tuned.state_dict()[k])
        assert torch.allclose(t, (full.tensors[k] + own[k]) / 2, atol=1e-6) and not torch.equal(t, own[k])
    assert half.version != full.version
    for bad in (0.0, 1.5):
        with pytest.raises(AdapterError, match="blend must be in"):
            adapter_from(base, tuned, "x", "v", blend=bad)


def test_saving_keeps_adapters_of_these_weights_and_drops_others(adapted, tmp_path, caplog):
    _, out, _ = adapted
    bundle = Bundle.load(out)
    bundle.save(tmp_path / "again", weights_dtype="float16")  # the same weights: the same version
    assert sorted(Bundle.load(tmp_path / "again").styles) == ["limp", "slow"]
    bundle.save(tmp_path / "wide")  # float32: another version, which the adapter was not tuned from
    assert "style adapters limp were tuned from model version" in caplog.text
    assert not (tmp_path / "wide" / "adapters").exists() and Bundle.load(tmp_path / "wide").adapters == {}
