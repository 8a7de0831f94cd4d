"""Packaging built-in styles: encode style clips with a bundle's own engine and store the codes in ``BUNDLE/styles/``.

This is the only place built-in styles are encoded (``rsmt package --styles``, ``rsmt bundle
add-styles``); the service serves the stored codes as they are. The engine is built from the bundle
as saved on disk (float16 weights widened on load, exactly as the server loads them), so the codes
are the ones the server would compute from the same clips (with its default single intra-op thread: more
threads change the last bits of a float sum). Encoding runs the float32 style encoder
whatever the bundle's inference settings: ``int8_lstm`` and the traced step change only the per-frame
step, never the style context.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path

import torch

from model.inference.bundle import Bundle, BundleError
from model.inference.bundle_adapters import StyleAdapter, save_adapters
from model.inference.bundle_styles import BuiltinStyle, StyleClip, StyleFolderError, check_name, save_styles
from model.inference.engine import Engine
from model.inference.errors import EngineError

ENCODE_THREADS = 1


@contextmanager
def server_threads() -> Iterator[None]:
    """Torch set to one intra-op thread inside, as `rsmt serve` runs by default (RSMT_THREADS=1), so codes get the
    server's float rounding; the caller's thread count comes back after."""
    threads = torch.get_num_threads()
    torch.set_num_threads(ENCODE_THREADS)
    try:
        yield
    finally:
        torch.set_num_threads(threads)


def encode_styles(engine: Engine, clips: Iterable[StyleClip]) -> list[BuiltinStyle]:
    """Each clip encoded by ``engine`` into a built-in style of the engine's model version."""
    out: list[BuiltinStyle] = []
    for item in clips:
        check_name(item.name)
        try:
            encoded, _ = engine.encode_style(item.clip, item.name)
        except EngineError as exc:
            raise StyleFolderError(f"style {item.name!r} ({item.source or 'clip'}): {exc}") from exc
        out.append(BuiltinStyle(item.name, encoded.frames, encoded.context, engine.version, item.source))
    return out


def write_builtin_styles(bundle: str | Path, clips: Iterable[StyleClip]) -> tuple[Path, list[BuiltinStyle]]:
    """Replace ``BUNDLE/styles/`` with the codes of ``clips`` (weights, config and adapters untouched); returns
    the folder and the styles. The bundle is read without its old styles folder, which may be of another
    format or other weights; what is written is loaded back before returning."""
    bundle = Path(bundle)
    loaded = Bundle.load(bundle, styles=False)
    clips = list(clips)
    taken = sorted({c.name for c in clips} & set(loaded.adapters))
    if taken:
        raise StyleFolderError(f"{bundle}: {', '.join(taken)} already built in with weights of their own (adapters/); "
                               "name the clips otherwise")
    with server_threads():
        styles = encode_styles(Engine(loaded), clips)
    folder = save_styles(bundle, styles, loaded.skeleton, loaded.config.fps, loaded.version)
    try:
        Bundle.load(bundle)
    except BundleError as exc:  # what was written must load
        raise StyleFolderError(str(exc)) from exc
    return folder, styles


def write_adapter(bundle: str | Path, adapter: StyleAdapter, clip: StyleClip) -> BuiltinStyle:
    """Add ``adapter`` to the bundle folder, with the code of ``clip`` encoded by the adapted weights as its
    built-in style (``builtin:NAME``); the bundle's weights, styles and other adapters stay as they are.
    What is written is loaded back before returning."""
    bundle = Path(bundle)
    loaded = Bundle.load(bundle)
    if adapter.name in loaded.styles:
        raise StyleFolderError(f"{bundle} already has a built-in style {adapter.name!r}: pick another name")
    if adapter.base_version != loaded.version:
        raise StyleFolderError(f"the adapter {adapter.name!r} was tuned from model version {adapter.base_version}, "
                               f"not from {bundle} (version {loaded.version})")
    loaded.adapters[adapter.name] = adapter
    with server_threads():
        try:
            encoded, _ = Engine(loaded).encode_style(clip.clip, adapter.name, weights=adapter.name)
        except EngineError as exc:
            raise StyleFolderError(f"style {adapter.name!r} ({clip.source or 'clip'}): {exc}") from exc
    style = BuiltinStyle(adapter.name, encoded.frames, encoded.context, adapter.version, clip.source,
                         weights=adapter.name)
    save_adapters(bundle, loaded.adapters, {**loaded.styles, adapter.name: style}, loaded.skeleton, loaded.config.fps)
    try:
        Bundle.load(bundle)
    except BundleError as exc:  # what was written must load
        raise StyleFolderError(str(exc)) from exc
    return style
