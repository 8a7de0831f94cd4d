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

The split never depends on this setting: it hashes and groups by the data's own name. The index
(:func:`model.data.takes.index_takes`) applies it with :func:`model.data.takes.relabel`.
"""

from __future__ import annotations

MODES = ("own", "merged")
DATASET1_TO_DATASET2 = {"old": "elderly", "tired": "exhausted", "childish": "youthful", "masculinity": "masculine"}
"""Dataset-1 style -> the dataset-2 style of about the same meaning (same-named ones are the same label anyway)."""


def check_mode(mode: str) -> str:
    if mode not in MODES:
        raise ValueError(f"style labels must be one of {', '.join(MODES)}, got {mode!r}")
    return mode

