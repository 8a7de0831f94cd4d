"""Style labels of a second data set beside the first: kept as the data names them, or merged by meaning.

Bandai-Namco dataset 1 names some styles differently from dataset 2 although they mean about the
same (old ~ elderly, tired ~ exhausted, childish ~ youthful, masculinity ~ masculine); active,
feminine and normal have the same name in both. Whether a model does better with one label or two
per pair is measured on val, so the choice is a data setting (``RSMT_STYLE_LABELS``, read by
:mod:`model.data.location`):

* ``own`` (default): every take keeps the style its file names; same-named styles of the two sets
  are one label, the differently named pairs stay two.
* ``merged``: dataset-1's ``old``, ``tired``, ``childish`` and ``masculinity`` are relabelled with
  dataset 2's name (the take's :attr:`~model.data.takes.Take.source_style` keeps the original).

The split never depends on this setting: it hashes and groups by the data's own name.
"""

from __future__ import annotations

from dataclasses import replace

from model.data.takes import Take

MODES = ("own", "merged")
DEFAULT_MODE = "own"
DATASET1_TO_DATASET2 = {"old": "elderly", "tired": "exhausted", "childish": "youthful", "masculinity": "masculine"}
"""Dataset-1 style -> the dataset-2 style of about the same meaning (same-named ones are the same label anyway)."""


def check_mode(mode: str) -> str:
    if mode not in MODES:
        raise ValueError(f"style labels must be one of {', '.join(MODES)}, got {mode!r}")
    return mode


def relabel(take: Take, mode: str) -> Take:
    """``take`` with the style label ``mode`` gives it (the same object when unchanged)."""
    check_mode(mode)
    if mode == "merged" and take.source == "dataset-1" and take.data_style in DATASET1_TO_DATASET2:
        return replace(take, style=DATASET1_TO_DATASET2[take.data_style], source_style=take.data_style)
    return take
