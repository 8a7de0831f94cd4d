"""Built-in styles of a bundle: a ``styles/`` folder beside the weights, served as ``builtin:NAME``.

Layout::

    BUNDLE/styles/
      styles.json          format, the model version the codes belong to, fps, the rig's joint names,
                           and per style: name, frames (of the clip it was encoded from), source
      codes.safetensors    per style ``NAME/FIELD`` for every field of the sampler's style context
                           (:class:`model.nets.sampler.StyleContext`: FiLM gains and biases, attention
                           keys and values, mask), float32 (the mask bool), batch of one; no pickle

The folder holds encoded style codes only, no motion: they are made at packaging time
(:mod:`model.inference.style_packing`) by the bundle's own engine, and served as they are. Codes
belong to the weights that made them: the folder names that model version, and a bundle whose
weights are another version does not load (re-encode with ``rsmt bundle add-styles``). Style ids
of built-in styles are names, not hashes, so the folder can be replaced without touching
``config.json`` or ``weights.safetensors``.
"""

from __future__ import annotations

import json
import math
import re
import shutil
from collections.abc import Iterable
from dataclasses import dataclass, fields
from pathlib import Path

import torch
from safetensors import safe_open
from safetensors.torch import load_file, save_file

from model.motion.bvh_clip import load_clip
from model.motion.clip import Clip
from model.motion.kinematics import forward_kinematics, global_to_local_rotations
from model.motion.skeleton import BUILTIN_PROFILES, Skeleton, plain_joint_name
from model.nets.sampler import StyleContext

STYLES_DIR = "styles"
STYLES_FORMAT = "rsmt-styles/2"
CLIPS_FORMAT = "rsmt-styles/1"  # the older folder of motion clips, encoded on first use; no longer read
CODES_FILE = "codes.safetensors"
NAME_PATTERN = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,63}$")
CONTEXT_FIELDS = tuple(f.name for f in fields(StyleContext))
REENCODE = ("re-encode them from their clips with `rsmt bundle add-styles BUNDLE --from DIR` (one BVH per style) "
            "or `--from-data DATA` (the default model's walking clips)")


class StyleFolderError(ValueError):
    """A style folder (in a bundle, or of BVH clips to encode) that cannot be read or written."""


@dataclass(frozen=True)
class StyleClip:
    """A style clip to encode into a built-in style (packaging time only: bundles store codes, not clips)."""

    name: str
    clip: Clip
    source: str = ""

    @property
    def frames(self) -> int:
        return self.clip.num_frames


@dataclass(frozen=True, eq=False)
class BuiltinStyle:
    """One built-in style (id ``builtin:NAME``): its encoded context, the model version that encoded it,
    the length of the clip it came from, where that clip came from, and the weights it runs on: the
    bundle's own (``""``) or those of the adapter of that name (:mod:`model.inference.bundle_adapters`)."""

    name: str
    frames: int
    context: StyleContext
    version: str
    source: str = ""
    weights: str = ""

    @property
    def nbytes(self) -> int:
        return self.context.nbytes


def check_name(name: str) -> str:
    if not NAME_PATTERN.match(name):
        raise StyleFolderError(f"style name {name!r}: use 1-64 letters, digits, '_', '-' or '.', starting with a "
                               "letter or digit (it becomes the id builtin:NAME)")
    return name


def save_styles(bundle: str | Path, styles: Iterable[BuiltinStyle], skeleton: Skeleton, fps: float,
                version: str) -> Path:
    """Write ``BUNDLE/styles/`` (replacing any older one); every style must be encoded by model ``version``."""
    folder = Path(bundle) / STYLES_DIR
    tensors: dict[str, torch.Tensor] = {}
    entries = []
    for s in sorted(styles, key=lambda s: s.name):
        check_name(s.name)
        if f"{s.name}/mask" in tensors:
            raise StyleFolderError(f"two built-in styles are named {s.name!r}")
        if s.version != version:
            raise StyleFolderError(f"style {s.name!r} was encoded by model version {s.version}, not by this bundle's "
                                   f"weights (version {version}): {REENCODE.replace('BUNDLE', str(bundle))}")
        for f in CONTEXT_FIELDS:
            t = getattr(s.context, f).detach().cpu()
            tensors[f"{s.name}/{f}"] = (t if f == "mask" else t.to(torch.float32)).contiguous()
        entries.append({"name": s.name, "frames": s.frames, "source": s.source})
    if folder.exists():
        shutil.rmtree(folder)
    if not entries:
        return folder
    folder.mkdir(parents=True)
    save_file(tensors, str(folder / CODES_FILE), metadata={"format": STYLES_FORMAT, "version": version})
    index = {"format": STYLES_FORMAT, "version": version, "fps": fps, "joints": list(skeleton.names),
             "styles": entries}
    (folder / "styles.json").write_text(json.dumps(index, indent=1) + "\n")
    return folder


def _check_index(folder: Path, skeleton: Skeleton, fps: float, version: str) -> None:
    """``styles.json`` and the codes file are of this format, these weights, this rig and this fps."""
    try:
        index = json.loads((folder / "styles.json").read_text())
    except json.JSONDecodeError as exc:
        raise StyleFolderError(f"{folder}/styles.json is not valid JSON: {exc}") from exc
    fix = REENCODE.replace("BUNDLE", str(folder.parent))
    if index.get("format") == CLIPS_FORMAT:
        raise StyleFolderError(f"{folder} holds style clips (format {CLIPS_FORMAT}); bundles now carry encoded style "
                               f"codes ({STYLES_FORMAT}): {fix}")
    if index.get("format") != STYLES_FORMAT:
        raise StyleFolderError(f"{folder}: unsupported styles format {index.get('format')!r} (expected {STYLES_FORMAT})")
    if index.get("version") != version:
        raise StyleFolderError(f"{folder}: the style codes were encoded by model version {index.get('version')}, but "
                               f"this bundle's weights are version {version} (codes of other weights mean nothing to "
                               f"these): {fix}")
    if index.get("joints") != list(skeleton.names):
        raise StyleFolderError(f"{folder}: the style codes were encoded on another rig than the bundle's skeleton.json")
    if abs(float(index.get("fps", 0)) - fps) > 1e-6:
        raise StyleFolderError(f"{folder}: the style codes are at {index.get('fps')} fps, the model at {fps:g}")
    path = folder / CODES_FILE
    if not path.is_file():
        raise StyleFolderError(f"{folder}: {CODES_FILE} is missing")
    with safe_open(str(path), framework="pt") as f:
        stored = (f.metadata() or {}).get("version")
    if stored != version:
        raise StyleFolderError(f"{path}: the codes were encoded by model version {stored}, but this bundle's weights "
                               f"are version {version}: {fix}")


def load_styles(bundle: str | Path, skeleton: Skeleton, fps: float, version: str) -> dict[str, BuiltinStyle]:
    """The built-in styles of a bundle whose weights are model ``version``, by name; empty when it has no
    ``styles/`` folder. Codes of another version, or a folder of the older clip format, are errors."""
    folder = Path(bundle) / STYLES_DIR
    if not (folder / "styles.json").is_file():
        return {}
    _check_index(folder, skeleton, fps, version)
    index = json.loads((folder / "styles.json").read_text())
    path = folder / CODES_FILE
    tensors = load_file(str(path))
    out: dict[str, BuiltinStyle] = {}
    for entry in index.get("styles", []):
        name = check_name(str(entry.get("name", "")))
        missing = [f for f in CONTEXT_FIELDS if f"{name}/{f}" not in tensors]
        if missing:
            raise StyleFolderError(f"{folder}: the code of style {name!r} is missing from {CODES_FILE} "
                                   f"({', '.join(missing)})")
        parts = {f: tensors[f"{name}/{f}"] for f in CONTEXT_FIELDS}
        if any(t.shape[0] != 1 for t in parts.values()):
            raise StyleFolderError(f"{folder}: the code of style {name!r} is not a batch of one")
        context = StyleContext(**{f: t if f == "mask" else t.float() for f, t in parts.items()})
        out[name] = BuiltinStyle(name, int(entry.get("frames", 0)), context, version, str(entry.get("source", "")))
    return out


def clip_on_rig(clip: Clip, skeleton: Skeleton, fps: float, what: str) -> Clip:
    """``clip`` on ``skeleton`` at ``fps``, joints matched by name in world space as the engine conforms a
    request's motion (extra joints dropped). The rest pose must agree: a bone pointing another way at rest
    (another rig with the same names) would bend the pose, so it is an error rather than a silent distortion."""
    lookup = {plain_joint_name(n).lower(): i for i, n in enumerate(clip.skeleton.names)}
    missing = [n for n in skeleton.names if plain_joint_name(n).lower() not in lookup]
    if missing:
        raise StyleFolderError(f"{what}: lacks joint(s) of the model's skeleton: {', '.join(missing)}")
    idx = [lookup[plain_joint_name(n).lower()] for n in skeleton.names]
    rest = forward_kinematics(torch.tensor([[[0.0, 0.0, 0.0, 1.0]] * clip.skeleton.num_joints]), torch.zeros(1, 3),
                              clip.skeleton.offsets_tensor(torch.float32), clip.skeleton.parents)[0][0, idx]
    for j, p in enumerate(skeleton.parents):
        want = torch.tensor(skeleton.offsets[j], dtype=torch.float32)
        have = rest[j] - rest[p] if p >= 0 else want
        if p >= 0 and want.norm() > 2.0 and have.norm() > 2.0 and \
                float(torch.dot(want, have) / (want.norm() * have.norm())) < math.cos(math.radians(20)):
            raise StyleFolderError(f"{what}: its rest pose differs from the model's at joint {skeleton.names[j]!r} "
                                   "(the bone points another way): export the clip on the model's rig")
    pos, grot = clip.global_transforms()
    out = Clip(skeleton, global_to_local_rotations(grot[:, idx], skeleton.parents).to(torch.float32),
               pos[:, idx[0]].to(torch.float32), clip.fps, clip.name)
    return out if abs(out.fps - fps) < 1e-6 else out.resample(fps)


def read_style_bvh(path: Path, skeleton: Skeleton, fps: float, start: int = 0, frames: int | None = None) -> Clip:
    """Frames ``[start, start + frames)`` of a BVH file (at the model's fps) on the model's rig."""
    profile = skeleton.roles.profile if skeleton.roles.profile in BUILTIN_PROFILES else None
    clip = clip_on_rig(load_clip(path, profile=profile), skeleton, fps, str(path))
    stop = clip.num_frames if frames is None else start + frames
    if not 0 <= start < stop <= clip.num_frames:
        raise StyleFolderError(f"{path}: frames [{start}, {stop}) are outside its {clip.num_frames} frames at {fps:g} fps")
    return clip.window(start, stop)


def styles_from_folder(folder: Path, skeleton: Skeleton, fps: float) -> list[StyleClip]:
    """One style per BVH file of ``folder`` (named by its stem), or per sub-folder (named by it; its first
    BVH file, in name order, is the clip)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise StyleFolderError(f"--styles {folder}: not a folder")
    found: list[StyleClip] = []
    for entry in sorted(folder.iterdir()):
        if entry.name.startswith("."):
            continue
        if entry.is_dir():
            clips = sorted(p for p in entry.iterdir() if p.suffix.lower() == ".bvh")
            if clips:
                found.append(StyleClip(check_name(entry.name), read_style_bvh(clips[0], skeleton, fps),
                                          f"{entry.name}/{clips[0].name}"))
        elif entry.suffix.lower() == ".bvh":
            found.append(StyleClip(check_name(entry.stem), read_style_bvh(entry, skeleton, fps), entry.name))
    if not found:
        raise StyleFolderError(f"--styles {folder}: no BVH files (one per style) and no folders of them")
    return found
