"""A motion database: the compressed poses of locomotion segments, per style and content, that a bundle carries
for motion matching (``BUNDLE/database.safetensors`` beside ``database.json``).

What it stores, per frame: local rotations packed in 32 bits each (:mod:`model.retrieval.quat_packing`: within
0.3 degree) and the root position in whole millimetres,
on the ground relative to its segment's first frame and in height as captured (int16: segments up to 32 m). Per
segment: its first row, its length, its style and its content. The matching features are not stored:
:mod:`model.retrieval.matching` computes them from the poses when the database is loaded (a few seconds for tens of
thousands of frames), so the file holds poses alone and the features can change without rebuilding it.

A database holds segments, never whole takes: each take's first and last frames are left out (``trim``), and a
build keeps within a byte budget (:mod:`model.data.database_build`).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
from safetensors.torch import load_file, save_file

from model.motion.skeleton import Skeleton
from model.retrieval.quat_packing import pack_quaternions, unpack_quaternions

Tensor = torch.Tensor
DATABASE_FILE = "database.safetensors"
DATABASE_META = "database.json"
DATABASE_FORMAT = "rsmt-motion-database/1"
_MAX_MM = 32767


class DatabaseError(ValueError):
    """A database file that is missing a part, of another format, or on another rig."""


def bytes_per_frame(joints: int) -> int:
    """What one frame costs in the file: a 32-bit rotation a joint and an int16 root."""
    return joints * 4 + 3 * 2


@dataclass
class MotionDatabase:
    """Segments of real motion on one rig (``skeleton``) at ``fps``: rows ``[N]`` of poses, grouped in segments.

    ``rotations [N, J]`` int32 (packed), ``roots_mm [N, 3]`` int16 (x, z relative to the segment's first frame, y as is),
    ``starts [S]`` / ``lengths [S]`` int32, ``style [S]`` / ``content [S]`` int32 indexes into ``styles`` /
    ``contents``; ``source`` says what it was built from."""

    skeleton: Skeleton
    fps: float
    rotations: Tensor
    roots_mm: Tensor
    starts: Tensor
    lengths: Tensor
    style: Tensor
    content: Tensor
    styles: list[str]
    contents: list[str]
    source: str = ""

    @classmethod
    def from_segments(cls, skeleton: Skeleton, fps: float, segments: list[tuple[Tensor, Tensor, str, str]],
                      source: str = "") -> MotionDatabase:
        """A database of ``(local rotations [T, J, 4], root positions [T, 3] cm, style, content)`` segments."""
        if not segments:
            raise DatabaseError("a motion database needs at least one segment")
        styles = sorted({s for _, _, s, _ in segments})
        contents = sorted({c for _, _, _, c in segments})
        rots, roots, lengths = [], [], []
        for rot, root, _, _ in segments:
            if rot.shape[1:] != (skeleton.num_joints, 4) or root.shape != (rot.shape[0], 3):
                raise DatabaseError(f"a segment of shape {tuple(rot.shape)} / {tuple(root.shape)} is not on the "
                                    f"{skeleton.num_joints}-joint rig")
            rel = torch.round((root - root[:1] * torch.tensor([1.0, 0.0, 1.0])).double() * 10.0)
            if float(rel.abs().max()) > _MAX_MM:
                raise DatabaseError(f"a segment travels {float(rel.abs().max()) / 1000:.1f} m: segments are at "
                                    "most 32 m long; cut it")
            rots.append(pack_quaternions(rot))
            roots.append(rel.to(torch.int16))
            lengths.append(rot.shape[0])
        lens = torch.tensor(lengths, dtype=torch.int32)
        starts = torch.cumsum(lens, 0, dtype=torch.int32) - lens
        return cls(skeleton, float(fps), torch.cat(rots), torch.cat(roots), starts, lens,
                   torch.tensor([styles.index(s) for _, _, s, _ in segments], dtype=torch.int32),
                   torch.tensor([contents.index(c) for _, _, _, c in segments], dtype=torch.int32),
                   styles, contents, source)

    @property
    def frames(self) -> int:
        return int(self.rotations.shape[0])

    @property
    def nbytes(self) -> int:
        return sum(t.numel() * t.element_size() for t in (self.rotations, self.roots_mm, self.starts, self.lengths,
                                                           self.style, self.content))

    def local_rotations(self) -> Tensor:
        """Every row's local rotations ``[N, J, 4]`` (float32, unit)."""
        return unpack_quaternions(self.rotations)

    def root_positions(self) -> Tensor:
        """Every row's root position ``[N, 3]`` in cm, on the ground relative to its segment's first frame."""
        return self.roots_mm.float() / 10.0

    def segment_of_rows(self) -> Tensor:
        """The segment of every row ``[N]``."""
        return torch.repeat_interleave(torch.arange(len(self.starts)), self.lengths.long())

    def rows_of_style(self, style: str) -> Tensor:
        """A ``[N]`` mask of the rows of ``style`` (all False for a style it lacks)."""
        if style not in self.styles:
            return torch.zeros(self.frames, dtype=torch.bool)
        return (self.style == self.styles.index(style))[self.segment_of_rows()]

    def describe(self) -> dict[str, Any]:
        per_style = {s: int(self.lengths[self.style == i].sum()) for i, s in enumerate(self.styles)}
        return {"frames": self.frames, "segments": len(self.starts), "seconds": round(self.frames / self.fps, 1),
                "bytes": self.nbytes, "styles": per_style, "contents": self.contents, "source": self.source}

    # ------------------------------------------------------------------ files
    def save(self, folder: str | Path) -> Path:
        """Write ``database.safetensors`` and ``database.json`` into ``folder`` (a bundle); returns the first."""
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        path = folder / DATABASE_FILE
        save_file({"rotations": self.rotations.contiguous(), "roots_mm": self.roots_mm.contiguous(),
                   "starts": self.starts, "lengths": self.lengths, "style": self.style, "content": self.content},
                  str(path), metadata={"format": DATABASE_FORMAT})
        meta = {"format": DATABASE_FORMAT, "fps": self.fps, "joints": list(self.skeleton.names), "styles": self.styles,
                "contents": self.contents, "source": self.source,
                "licence": "poses derived from the training data: its licence applies (CC BY-NC 4.0 for the "
                           "Bandai-Namco sets)"}
        (folder / DATABASE_META).write_text(json.dumps(meta, indent=1))
        return path

    @classmethod
    def load(cls, folder: str | Path, skeleton: Skeleton) -> MotionDatabase | None:
        """The database of ``folder`` (a bundle) on ``skeleton``'s rig; None where it has none."""
        folder = Path(folder)
        path, meta_path = folder / DATABASE_FILE, folder / DATABASE_META
        if not path.is_file():
            return None
        if not meta_path.is_file():
            raise DatabaseError(f"{folder}: {DATABASE_FILE} without {DATABASE_META}")
        meta = json.loads(meta_path.read_text())
        if meta.get("format") != DATABASE_FORMAT:
            raise DatabaseError(f"{folder}: unsupported database format {meta.get('format')!r} "
                                f"(expected {DATABASE_FORMAT})")
        if meta.get("joints") != list(skeleton.names):
            raise DatabaseError(f"{folder}: the database is on another rig than the bundle's (its joints: "
                                f"{', '.join(meta.get('joints', [])[:4])}...); build it again from the bundle's data")
        t = load_file(str(path))
        missing = sorted({"rotations", "roots_mm", "starts", "lengths", "style", "content"} - set(t))
        if missing:
            raise DatabaseError(f"{folder}: {DATABASE_FILE} lacks {', '.join(missing)}")
        db = cls(skeleton, float(meta["fps"]), t["rotations"], t["roots_mm"], t["starts"], t["lengths"], t["style"],
                 t["content"], list(meta["styles"]), list(meta["contents"]), str(meta.get("source", "")))
        if int(db.lengths.sum()) != db.frames or db.rotations.shape[1:] != (skeleton.num_joints,):
            raise DatabaseError(f"{folder}: the database's segments do not add up to its {db.frames} frames")
        return db
