"""Built-in style clips of a bundle: a ``styles/`` folder beside the weights, served as ``builtin:NAME``.

Layout::

    BUNDLE/styles/
      styles.json          format, fps, the rig's joint names, and per style: name, frames, source
      clips.safetensors    per style ``NAME/rotations`` [T, J, 4] (local x, y, z, w) and
                           ``NAME/root_positions`` [T, 3], float32 (no pickle)

The folder is independent of the weights: it can be written, replaced or removed without touching
``config.json`` or ``weights.safetensors`` (style ids of built-in styles are names, not hashes).
Clips are stored on the bundle's own rig and at its fps, so they need no conversion when served.
"""

from __future__ import annotations

import json
import math
import re
import shutil
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import torch
from safetensors.torch import load_file, save_file

from model.motion.bvh_clip import load_clip
from model.motion.clip import Clip
from model.motion.kinematics import forward_kinematics, global_to_local_rotations
from model.motion.skeleton import BUILTIN_PROFILES, Skeleton, plain_joint_name

STYLES_DIR = "styles"
STYLES_FORMAT = "rsmt-styles/1"
NAME_PATTERN = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,63}$")


class StyleFolderError(ValueError):
    """A style folder (in a bundle, or of BVH clips to add) that cannot be read or written."""


@dataclass(frozen=True)
class BuiltinStyle:
    """One built-in style: its name (the id is ``builtin:NAME``), its clip and where the clip came from."""

    name: str
    clip: Clip
    source: str = ""

    @property
    def frames(self) -> int:
        return self.clip.num_frames


def check_name(name: str) -> str:
    if not NAME_PATTERN.match(name):
        raise StyleFolderError(f"style name {name!r}: use 1-64 letters, digits, '_', '-' or '.', starting with a "
                               "letter or digit (it becomes the id builtin:NAME)")
    return name


def save_styles(bundle: str | Path, styles: Iterable[BuiltinStyle], skeleton: Skeleton, fps: float) -> Path:
    """Write ``BUNDLE/styles/`` (replacing any older one); every clip must be on ``skeleton`` at ``fps``."""
    folder = Path(bundle) / STYLES_DIR
    tensors: dict[str, torch.Tensor] = {}
    entries = []
    for s in sorted(styles, key=lambda s: s.name):
        check_name(s.name)
        if f"{s.name}/rotations" in tensors:
            raise StyleFolderError(f"two built-in styles are named {s.name!r}")
        if s.clip.skeleton.names != skeleton.names or s.clip.skeleton.parents != skeleton.parents:
            raise StyleFolderError(f"style {s.name!r} is not on the bundle's rig")
        if abs(s.clip.fps - fps) > 1e-6:
            raise StyleFolderError(f"style {s.name!r} is at {s.clip.fps:g} fps, the bundle at {fps:g}")
        tensors[f"{s.name}/rotations"] = s.clip.rotations.detach().to(torch.float32).contiguous()
        tensors[f"{s.name}/root_positions"] = s.clip.root_positions.detach().to(torch.float32).contiguous()
        entries.append({"name": s.name, "frames": s.frames, "source": s.source})
    if folder.exists():
        shutil.rmtree(folder)
    if not entries:
        return folder
    folder.mkdir(parents=True)
    save_file(tensors, str(folder / "clips.safetensors"), metadata={"format": STYLES_FORMAT})
    index = {"format": STYLES_FORMAT, "fps": fps, "joints": list(skeleton.names), "styles": entries}
    (folder / "styles.json").write_text(json.dumps(index, indent=1) + "\n")
    return folder


def load_styles(bundle: str | Path, skeleton: Skeleton, fps: float) -> dict[str, BuiltinStyle]:
    """The built-in styles of a bundle by name; empty when it has no ``styles/`` folder."""
    folder = Path(bundle) / STYLES_DIR
    if not (folder / "styles.json").is_file():
        return {}
    try:
        index = json.loads((folder / "styles.json").read_text())
    except json.JSONDecodeError as exc:
        raise StyleFolderError(f"{folder}/styles.json is not valid JSON: {exc}") from exc
    if index.get("format") != STYLES_FORMAT:
        raise StyleFolderError(f"{folder}: unsupported styles format {index.get('format')!r} (expected {STYLES_FORMAT})")
    if index.get("joints") != list(skeleton.names):
        raise StyleFolderError(f"{folder}: the style clips are on another rig than the bundle's skeleton.json")
    if abs(float(index.get("fps", 0)) - fps) > 1e-6:
        raise StyleFolderError(f"{folder}: the style clips are at {index.get('fps')} fps, the model at {fps:g}")
    if not (folder / "clips.safetensors").is_file():
        raise StyleFolderError(f"{folder}: clips.safetensors is missing")
    tensors = load_file(str(folder / "clips.safetensors"))
    out: dict[str, BuiltinStyle] = {}
    for entry in index.get("styles", []):
        name = check_name(str(entry.get("name", "")))
        rot, root = tensors.get(f"{name}/rotations"), tensors.get(f"{name}/root_positions")
        if rot is None or root is None:
            raise StyleFolderError(f"{folder}: the clip of style {name!r} is missing from clips.safetensors")
        try:
            clip = Clip(skeleton, rot.float(), root.float(), fps, f"builtin:{name}")
        except ValueError as exc:
            raise StyleFolderError(f"{folder}: style {name!r}: {exc}") from exc
        out[name] = BuiltinStyle(name, clip, str(entry.get("source", "")))
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


def styles_from_folder(folder: Path, skeleton: Skeleton, fps: float) -> list[BuiltinStyle]:
    """One style per BVH file of ``folder`` (named by its stem), or per sub-folder (named by it; its first
    BVH file, in name order, is the clip)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise StyleFolderError(f"--styles {folder}: not a folder")
    found: list[BuiltinStyle] = []
    for entry in sorted(folder.iterdir()):
        if entry.name.startswith("."):
            continue
        if entry.is_dir():
            clips = sorted(p for p in entry.iterdir() if p.suffix.lower() == ".bvh")
            if clips:
                found.append(BuiltinStyle(check_name(entry.name), read_style_bvh(clips[0], skeleton, fps),
                                          f"{entry.name}/{clips[0].name}"))
        elif entry.suffix.lower() == ".bvh":
            found.append(BuiltinStyle(check_name(entry.stem), read_style_bvh(entry, skeleton, fps), entry.name))
    if not found:
        raise StyleFolderError(f"--styles {folder}: no BVH files (one per style) and no folders of them")
    return found
