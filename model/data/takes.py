"""Index of a folder of BVH takes: each file's style and content labels, frame cuts, and the problems found.

Three layouts are understood, chosen in this order:

1. ``manifest``: a CSV with columns ``file, style, content`` and optional ``start, stop`` (source
   frames, ``[start, stop)``); file paths are relative to the manifest. BVH files under the folder
   that the manifest does not list are reported as problems.
2. ``100style``: a ``Frame_Cuts.csv`` (columns ``STYLE_NAME`` and ``<CT>_START``/``<CT>_STOP``) with
   one folder per style holding ``<Style>_<CT>.bvh``. The cuts are in the files' own (60 fps)
   frame numbering; ``N/A`` or an empty cell means the take is skipped.
3. ``bandai-namco``: file names ``dataset-<N>_{content}_{style}_{NNN}.bvh`` (contents and styles may
   hold hyphens, never underscores).

BVH files are found recursively. A file the index cannot label becomes a :class:`Problem`, never an
exception.

Several folders (one string, separated by ``os.pathsep`` as in ``PATH``: ``RSMT_DATA=$D2:$D1``) are
indexed each on its own and read as one index: a take keeps the id it has in its own folder, so its
split is the same whether its folder is indexed alone or beside others.
"""

from __future__ import annotations

import csv
import os
import re
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TypeVar

from model.data.location import style_labels_setting
from model.data.style_labels import DATASET1_TO_DATASET2, check_mode
from model.motion.bvh_parser import frame_time_problem, is_number, whole_number

FRAME_CUTS = "Frame_Cuts.csv"
STYLE100_CONTENTS = ("BR", "BW", "FR", "FW", "ID", "SR", "SW", "TR1", "TR2", "TR3")
LAYOUTS = ("manifest", "100style", "bandai-namco")
_BANDAI_NAME = re.compile(r"dataset-(?P<set>\d+)_(?P<content>[^_]+)_(?P<style>[^_]+)_(?P<num>\d+)", re.IGNORECASE)
_MISSING_CUT = {"", "n/a", "na", "nan", "none", "-"}


@dataclass(frozen=True)
class Take:
    """One motion-capture take and its labels.

    Attributes:
        path: the BVH file.
        style: style label, e.g. ``"elderly"``.
        content: content label, e.g. ``"walk-turn-left"``.
        take_id: a stable identifier, unique in its index: the file's path relative to the indexed
            folder (or the manifest), without suffix, plus ``@start-stop`` when a manifest cuts
            one file into several takes. It never holds an absolute path, so hashes of it are the
            same on every machine.
        start / stop: optional cut ``[start, stop)`` in the file's own frame numbering.
        source_style: the style as the data names it when ``style`` is a merged label
            (:mod:`model.data.style_labels`); ``None`` when they are the same.
    """

    path: Path
    style: str
    content: str
    take_id: str
    start: int | None = None
    stop: int | None = None
    source_style: str | None = None

    @property
    def data_style(self) -> str:
        """The style as the data names it (before any label merge)."""
        return self.source_style or self.style

    @property
    def source(self) -> str:
        """The data set a Bandai-Namco take comes from (``"dataset-1"``, ``"dataset-2"``); ``""`` for other layouts."""
        m = _BANDAI_NAME.fullmatch(self.path.stem)
        return f"dataset-{int(m['set'])}" if m else ""

    @property
    def key(self) -> str:
        """The machine-independent key that splits hash (the data's own style, so a label merge moves no take)."""
        return f"{self.data_style}/{self.content}/{self.take_id}"


@dataclass(frozen=True)
class Problem:
    """A file that was skipped, and why.

    Attributes:
        path: the file (relative to the indexed folder when it lies inside it).
        kind: ``unlabelled``, ``missing``, ``skipped`` (no frame cut), ``unreadable`` (not valid
            BVH), ``rig`` (the skeleton profile does not fit), ``too-short`` or ``bad-cut``.
        message: what went wrong, for a person.
    """

    path: str
    kind: str
    message: str

    def __str__(self) -> str:
        return f"{self.path}: [{self.kind}] {self.message}"


@dataclass
class TakeIndex:
    """The result of :func:`index_takes`.

    Attributes:
        root: the folder that was indexed.
        layout: one of :data:`LAYOUTS`.
        takes: labelled takes, sorted by ``take_id``.
        problems: files that could not be labelled.
        manifest: the manifest used, if any.
        roots: every folder indexed when there are several (``root`` is the first); empty for one.
    """

    root: Path
    layout: str
    takes: list[Take] = field(default_factory=list)
    problems: list[Problem] = field(default_factory=list)
    manifest: Path | None = None
    roots: tuple[Path, ...] = ()

    @property
    def styles(self) -> list[str]:
        return sorted({t.style for t in self.takes})

    @property
    def contents(self) -> list[str]:
        return sorted({t.content for t in self.takes})


def find_bvh_files(folder: Path) -> list[Path]:
    """Every ``.bvh`` file under ``folder`` (any depth, any case of the suffix), sorted; hidden folders are skipped."""
    found: list[Path] = []
    for dirpath, dirnames, filenames in os.walk(folder):
        dirnames[:] = sorted(d for d in dirnames if not d.startswith("."))
        found.extend(Path(dirpath) / f for f in filenames if f.lower().endswith(".bvh") and not f.startswith("."))
    return sorted(found)


def relative_path(path: Path, root: Path) -> str:
    """``path`` relative to ``root`` in POSIX form (with ``..`` when it lies outside), for messages and keys."""
    try:
        return path.relative_to(root).as_posix()
    except ValueError:
        return Path(os.path.relpath(path, root)).as_posix()


def _stem_id(path: Path, root: Path) -> str:
    rel = relative_path(path, root)
    return rel[: -len(path.suffix)] if path.suffix else rel


def parse_bandai_namco_name(name: str) -> tuple[str, str] | None:
    """``(content, style)`` from a Bandai-Namco file name, or ``None`` when it does not follow the pattern."""
    m = _BANDAI_NAME.fullmatch(Path(name).stem)
    return (m["content"].lower(), m["style"].lower()) if m else None


def data_folders(folder: str | Path) -> list[Path]:
    """The folders ``folder`` names: one, or several separated by ``os.pathsep``."""
    return [Path(part).expanduser() for part in str(folder).split(os.pathsep) if part]


def index_takes(folder: str | Path, manifest: str | Path | None = None, style_labels: str | None = None) -> TakeIndex:
    """Label every BVH take under ``folder`` (or under each of several folders, see the module docstring).

    The layout is ``manifest`` when one is given, else ``100style`` when a ``Frame_Cuts.csv`` lies in
    ``folder`` (or, failing that, anywhere below it), else ``bandai-namco``. ``style_labels`` is a mode of
    :mod:`model.data.style_labels` (default: the ``RSMT_STYLE_LABELS`` setting, else ``own``).

    Raises:
        FileNotFoundError: ``folder`` or ``manifest`` does not exist.
        ValueError: the manifest or ``Frame_Cuts.csv`` lacks a required column; several folders with a manifest.
    """
    mode = style_labels or style_labels_setting()
    folders = data_folders(folder)
    if len(folders) > 1:
        if manifest is not None:
            raise ValueError("a manifest labels one data folder; give one folder with --manifest")
        index = _index_several(folders)
    else:
        index = _index_one(folder, manifest)
    index.takes = [relabel(t, mode) for t in index.takes]
    return index


def relabel(take: Take, mode: str) -> Take:
    """``take`` with the style label ``mode`` (:mod:`model.data.style_labels`) gives it; the same object when unchanged."""
    check_mode(mode)
    if mode == "merged" and take.source == "dataset-1" and take.data_style in DATASET1_TO_DATASET2:
        return replace(take, style=DATASET1_TO_DATASET2[take.data_style], source_style=take.data_style)
    return take


def _index_several(folders: list[Path]) -> TakeIndex:
    """One index of several folders: each indexed alone, the takes of all together (ids kept)."""
    parts = [_index_one(f) for f in folders]
    first = parts[0]
    layouts = sorted({p.layout for p in parts})
    index = TakeIndex(root=first.root, layout=layouts[0] if len(layouts) == 1 else "+".join(layouts),
                      roots=tuple(p.root for p in parts))
    seen: dict[str, Path] = {}
    for part in parts:
        index.problems += [replace(p, path=relative_path(part.root / p.path, first.root)) for p in part.problems]
        for take in part.takes:
            if take.take_id in seen:
                index.problems.append(Problem(relative_path(take.path, first.root), "unlabelled",
                                              f"take id {take.take_id} is also in {seen[take.take_id]}"))
                continue
            seen[take.take_id] = part.root
            index.takes.append(take)
    index.takes.sort(key=lambda t: t.take_id)
    return index


def _index_one(folder: str | Path, manifest: str | Path | None = None) -> TakeIndex:
    root = Path(folder).expanduser().resolve()
    if not root.is_dir():
        raise FileNotFoundError(f"no such data folder: {folder}")
    if manifest is not None:
        return _index_manifest(root, Path(manifest).expanduser().resolve())
    cuts = root / FRAME_CUTS
    if not cuts.is_file():
        below = sorted(root.rglob(FRAME_CUTS))
        cuts = below[0] if below else cuts
    if cuts.is_file():
        return _index_100style(root, cuts)
    return _index_bandai_namco(root)


# ---------------------------------------------------------------------------------- layouts
def _index_bandai_namco(root: Path) -> TakeIndex:
    index = TakeIndex(root=root, layout="bandai-namco")
    for path in find_bvh_files(root):
        labels = parse_bandai_namco_name(path.name)
        if labels is None:
            index.problems.append(Problem(
                relative_path(path, root), "unlabelled",
                "file name does not follow dataset-<N>_{content}_{style}_{NNN}.bvh"))
            continue
        content, style = labels
        index.takes.append(Take(path=path, style=style, content=content, take_id=_stem_id(path, root)))
    index.takes.sort(key=lambda t: t.take_id)
    return index


def _parse_cut(value: str | None) -> int | None:
    """A frame number, ``None`` for a missing cut; ``ValueError`` for anything else."""
    text = (value or "").strip()
    if text.lower() in _MISSING_CUT:
        return None
    number = float(text)  # some exports write "120.0"
    if number != int(number) or number < 0:
        raise ValueError(f"not a frame number: {text!r}")
    return int(number)


def _read_csv(path: Path) -> tuple[list[str], list[tuple[int, dict[str, str]]]]:
    """Column names and ``(line number, row)`` pairs; cells are stripped and a missing cell reads as ``""``."""
    # utf-8-sig: spreadsheet exports often start with a byte-order mark that would rename the first column.
    with path.open(newline="", encoding="utf-8-sig") as fh:
        reader = csv.reader(fh)
        header = next(reader, None)
        if header is None:
            raise ValueError(f"{path}: empty CSV file")
        columns = [c.strip() for c in header]
        records = []
        for values in reader:
            if not any(v.strip() for v in values):
                continue
            values = [v.strip() for v in values] + [""] * max(0, len(columns) - len(values))
            records.append((reader.line_num, dict(zip(columns, values))))
    return columns, records


def _index_100style(root: Path, cuts_file: Path) -> TakeIndex:
    index = TakeIndex(root=root, layout="100style")
    columns, rows = _read_csv(cuts_file)
    if "STYLE_NAME" not in columns:
        raise ValueError(f"{cuts_file}: Frame_Cuts.csv has no STYLE_NAME column")
    cuts: dict[str, dict[str, str]] = {}
    for _, row in rows:
        if row.get("STYLE_NAME"):
            cuts[row["STYLE_NAME"]] = row
    # Style folder names normally match STYLE_NAME exactly; case-insensitive matching forgives a renamed folder.
    by_lower = {name.lower(): name for name in cuts}
    pattern = re.compile(r"(?P<style>.+)_(?P<ct>" + "|".join(STYLE100_CONTENTS) + r")", re.IGNORECASE)
    for path in find_bvh_files(root):
        rel = relative_path(path, root)
        m = pattern.fullmatch(path.stem)
        if m is None:
            index.problems.append(Problem(rel, "unlabelled",
                                          f"file name is not <Style>_<CT>.bvh with CT in {' '.join(STYLE100_CONTENTS)}"))
            continue
        style = m["style"] if m["style"] in cuts else by_lower.get(m["style"].lower())
        if style is None:
            index.problems.append(Problem(rel, "unlabelled", f"style {m['style']!r} is not listed in {FRAME_CUTS}"))
            continue
        ct = m["ct"].upper()
        row = cuts[style]
        if f"{ct}_START" not in columns or f"{ct}_STOP" not in columns:
            index.problems.append(Problem(rel, "unlabelled", f"{FRAME_CUTS} has no {ct}_START/{ct}_STOP columns"))
            continue
        try:
            start, stop = _parse_cut(row[f"{ct}_START"]), _parse_cut(row[f"{ct}_STOP"])
        except ValueError as exc:
            index.problems.append(Problem(rel, "bad-cut", f"{FRAME_CUTS}, style {style}, {ct}: {exc}"))
            continue
        if start is None or stop is None:
            index.problems.append(Problem(rel, "skipped", f"{FRAME_CUTS} gives no frame cut for {style} {ct}"))
            continue
        if stop <= start:
            index.problems.append(Problem(rel, "bad-cut", f"{FRAME_CUTS}: {ct}_STOP {stop} is not after {ct}_START {start}"))
            continue
        index.takes.append(Take(path=path, style=style, content=ct, take_id=_stem_id(path, root), start=start, stop=stop))
    index.takes.sort(key=lambda t: t.take_id)
    return index


def _index_manifest(root: Path, manifest: Path) -> TakeIndex:
    if not manifest.is_file():
        raise FileNotFoundError(f"no such manifest: {manifest}")
    columns, rows = _read_csv(manifest)
    missing = [c for c in ("file", "style", "content") if c not in columns]
    if missing:
        raise ValueError(f"{manifest}: manifest lacks the column(s) {', '.join(missing)} "
                         "(expected file, style, content and optional start, stop)")
    index = TakeIndex(root=root, layout="manifest", manifest=manifest)
    listed: set[Path] = set()
    seen: dict[str, int] = {}
    for line, row in rows:
        item = _manifest_take(root, manifest, line, row, listed)
        if isinstance(item, Take) and item.take_id in seen:
            item = Problem(relative_path(item.path, root), "unlabelled",
                           f"{manifest.name}:{line} repeats the take of line {seen[item.take_id]}")
        if isinstance(item, Problem):
            index.problems.append(item)
            continue
        seen[item.take_id] = line
        index.takes.append(item)
    for path in find_bvh_files(root):
        if path.resolve() not in listed:
            index.problems.append(Problem(relative_path(path, root), "unlabelled", f"not listed in the manifest {manifest.name}"))
    index.takes.sort(key=lambda t: t.take_id)
    return index


def _manifest_take(root: Path, manifest: Path, line: int, row: dict[str, str], listed: set[Path]) -> Take | Problem:
    """The take one manifest row names, or the problem that keeps it out (its file is added to ``listed``)."""
    where = f"{manifest.name}:{line}"
    if not row.get("file"):
        return Problem(where, "unlabelled", "row without a file")
    base = manifest.parent
    path = (base / row["file"]).resolve()
    listed.add(path)
    rel = relative_path(path, root)
    if not path.is_file():
        return Problem(rel, "missing", f"listed in {where} but not found")
    style, content = row.get("style", ""), row.get("content", "")
    if not style or not content:
        return Problem(rel, "unlabelled", f"{where} gives no {'style' if not style else 'content'}")
    try:
        start, stop = _parse_cut(row.get("start")), _parse_cut(row.get("stop"))
    except ValueError as exc:
        return Problem(rel, "bad-cut", f"{where}: {exc}")
    if start is not None and stop is not None and stop <= start:
        return Problem(rel, "bad-cut", f"{where}: stop {stop} is not after start {start}")
    take_id = _stem_id(path, base)
    # A manifest may cut one file into several takes; the cut then disambiguates the id.
    if start is not None or stop is not None:
        take_id += f"@{'' if start is None else start}-{'' if stop is None else stop}"
    return Take(path=path, style=style, content=content, take_id=take_id, start=start, stop=stop)


# ---------------------------------------------------------------------------------- header probe
@dataclass(frozen=True)
class BvhHeader:
    """What the top of a BVH file says, read without parsing the motion.

    Attributes:
        joints: joint names in file order (ROOT and JOINT entries, End Sites excluded).
        frames: the ``Frames:`` count.
        frame_time: seconds per frame.
    """

    joints: tuple[str, ...]
    frames: int
    frame_time: float

    @property
    def fps(self) -> float:
        """``1 / frame_time``, snapped to a whole number within 1e-4 (files write 1/30 s as 0.0333333)."""
        fps = 1.0 / self.frame_time
        whole = round(fps)
        return float(whole) if whole >= 1 and abs(fps - whole) <= 1e-4 * fps else fps


def read_bvh_header(path: str | Path) -> BvhHeader:
    """Read a BVH file's hierarchy names and frame count, stopping before the motion data.

    It is much cheaper than a full parse, which is what ``rsmt data inspect`` needs to count frames
    over thousands of files; the full reader (:mod:`model.motion.bvh`) validates the rest.

    Raises:
        ValueError: the header is not valid BVH (the message names the file and line).
    """
    path = Path(path)
    joints: list[str] = []
    frames: int | None = None
    with path.open("r", encoding="utf-8", errors="replace") as fh:
        for lineno, raw in enumerate(fh, start=1):
            words = raw.split()
            if not words:
                continue
            head = words[0].upper()
            if lineno == 1 and head != "HIERARCHY" and not joints:
                raise ValueError(f"{path}:{lineno}: a BVH file starts with HIERARCHY, found {raw.strip()[:40]!r}")
            if head in ("ROOT", "JOINT"):
                if len(words) < 2:
                    raise ValueError(f"{path}:{lineno}: {words[0]} without a name")
                joints.append(" ".join(words[1:]))
            elif head == "FRAMES:":
                frames = _header_number(path, lineno, words, int)
            elif head == "FRAME" and len(words) >= 2 and words[1].upper() == "TIME:":
                if frames is None or not joints:
                    raise ValueError(f"{path}:{lineno}: 'Frame Time' before the joints and 'Frames:'")
                frame_time = _header_number(path, lineno, words[1:], float)
                if frame_time <= 0 or frames < 0:
                    raise ValueError(f"{path}:{lineno}: frame time and frame count must be positive")
                problem = frame_time_problem(frame_time)
                if problem is not None:
                    raise ValueError(f"{path}:{lineno}: {problem}")
                return BvhHeader(joints=tuple(joints), frames=frames, frame_time=frame_time)
    raise ValueError(f"{path}: no 'Frames:' and 'Frame Time:' lines (truncated file?)")


_N = TypeVar("_N", int, float)


def _header_number(path: Path, lineno: int, words: list[str], kind: type[_N]) -> _N:
    """The count or frame time on a header line: plain ASCII digits, as the full reader takes them (int() and
    float() also read "1_000" and non-ASCII digits)."""
    text = words[1] if kind is int and len(words) > 1 else words[-1] if len(words) > 1 else ""
    value = whole_number(text) if kind is int else float(text) if is_number(text) else None
    if value is None:
        raise ValueError(f"{path}:{lineno}: expected a number after {words[0]!r}")
    return kind(value)


def describe_layout(index: TakeIndex) -> str:
    """One line naming the layout and where the labels came from."""
    sources = {
        "manifest": f"manifest {index.manifest}",
        "100style": f"{FRAME_CUTS} and style folders",
        "bandai-namco": "file names dataset-<N>_{content}_{style}_{NNN}.bvh",
    }
    source = "; ".join(sources[layout] for layout in index.layout.split("+"))
    folders = f", {len(index.roots)} folders" if index.roots else ""
    return f"{index.layout} (labels from {source}{folders})"
