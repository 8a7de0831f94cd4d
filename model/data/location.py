"""Where the training motion data lives and where its preprocessed cache goes: the ``RSMT_DATA`` and
``RSMT_CACHE`` settings and their defaults (the only place the model package reads the environment).

``RSMT_DATA`` names a folder of BVH takes (searched recursively), e.g. the unpacked
Bandai-Namco dataset, or several folders separated by ``os.pathsep`` (``:``), read as one index
(:mod:`model.data.takes`): ``RSMT_DATA=~/.cache/rsmt-data/bandai-namco-motion-2:~/.cache/rsmt-data/bandai-namco-motion-1``
puts dataset 1 beside dataset 2 (a ``--data`` option takes the same form). Without it, the folder
that ``../shared/data/unpack.sh`` fills by default (``~/.cache/rsmt-data/bandai-namco-motion-2``) is
used when it is complete; :data:`DEFAULT_DATASET_1` is dataset 1's.

``RSMT_STYLE_LABELS`` chooses how a second data set's style labels sit beside the first's
(:mod:`model.data.style_labels`: ``own``, the default, or ``merged``).
"""

from __future__ import annotations

import os
from pathlib import Path

ENV_VAR = "RSMT_DATA"
DEFAULT_UNPACKED = Path.home() / ".cache" / "rsmt-data" / "bandai-namco-motion-2"
DEFAULT_DATASET_1 = Path.home() / ".cache" / "rsmt-data" / "bandai-namco-motion-1"
STYLE_LABELS_ENV = "RSMT_STYLE_LABELS"
CACHE_ENV = "RSMT_CACHE"
DEFAULT_CACHE_ROOT = Path.home() / ".cache" / "rsmt" / "preprocessed"


def find_data_dir() -> Path | None:
    """The configured motion-data folder, or ``None`` when there is none."""
    value = os.environ.get(ENV_VAR)
    if value:
        parts = [Path(p).expanduser() for p in value.split(os.pathsep) if p]
        if not parts or not all(p.is_dir() for p in parts):
            return None
        return parts[0] if len(parts) == 1 else Path(os.pathsep.join(str(p) for p in parts))
    if (DEFAULT_UNPACKED / ".complete").is_file():
        return DEFAULT_UNPACKED
    return None


def require_data_dir(given: Path | None) -> Path:
    """``given`` (a ``--data`` option), else the configured folder; an error saying how to name one when neither is set."""
    data = given or find_data_dir()
    if data is None:
        raise FileNotFoundError("no data folder: pass --data DIR or set RSMT_DATA")
    return data


def cache_root() -> Path:
    """Where preprocessed-data caches live: ``$RSMT_CACHE`` or ``~/.cache/rsmt/preprocessed``."""
    value = os.environ.get(CACHE_ENV)
    return Path(value).expanduser() if value else DEFAULT_CACHE_ROOT


def style_labels_setting() -> str:
    """The ``RSMT_STYLE_LABELS`` setting, default ``own`` (checked where it is used)."""
    return os.environ.get(STYLE_LABELS_ENV, "").strip() or "own"
