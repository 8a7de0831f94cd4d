"""Why a folder of takes gave an empty train or validation split, and what to run about it."""

from __future__ import annotations

from collections import Counter
from pathlib import Path

from model.data.preprocessed import MotionCache
from model.data.splits import Split

GUIDE = "docs/your-rig.md"


def empty_split_message(cache: MotionCache, split: Split, data_dir: Path, manifest: Path | None) -> str:
    """One message naming the cause (unlabelled files, a manifest that matched nothing, a rig no
    profile fits, unknown units, too few takes per group) and the command that helps."""
    kinds = Counter(p.kind for p in cache.problems)
    sizes = split.sizes()
    head = f"the data in {data_dir} gives an empty train or validation split: {sizes}"
    causes: list[str] = []
    if not cache.takes:
        if manifest is not None and kinds.get("missing"):
            causes.append(f"the manifest {manifest} matched no file: its {kinds['missing']} row(s) name files that "
                          f"are not there (paths are relative to the manifest's folder)")
        elif kinds.get("unlabelled") and manifest is None and cache.layout == "bandai-namco":
            causes.append(f"none of the {kinds['unlabelled']} BVH file(s) is labelled: their names do not follow "
                          "dataset-<N>_{content}_{style}_{NNN}.bvh and no manifest was given; write a CSV with "
                          "columns file,style,content and pass --manifest CSV")
        elif kinds.get("unlabelled"):
            causes.append(f"{kinds['unlabelled']} file(s) are unlabelled (see rsmt data inspect)")
        if kinds.get("rig"):
            causes.append(f"{kinds['rig']} take(s) on a rig that the skeleton profile does not fit: write one with "
                          f"rsmt profile guess {data_dir} --out my-rig.json, check it, and pass --profile my-rig.json")
        if kinds.get("units"):
            causes.append(f"{kinds['units']} take(s) in units that could not be told: pass --units (cm, m, inch or "
                          "centimetres per file unit)")
        other = {k: n for k, n in kinds.items() if k not in ("missing", "unlabelled", "rig", "units")}
        if other:
            causes.append("other skipped files: " + ", ".join(f"{k} {n}" for k, n in sorted(other.items())))
        if not causes:
            causes.append("the folder holds no BVH take")
    elif split.ratios[1] == 0:
        causes.append("the validation ratio is 0: give it a share (ratios such as 0.8,0.1,0.1)")
    else:
        groups = Counter((t.style, t.content) for i, t in enumerate(cache.takes) if i not in set(split.holdout))
        largest = max(groups.values(), default=0)
        causes.append(f"{len(cache.takes)} usable take(s) in {len(groups)} style x content group(s), the largest "
                      f"of {largest}: a group is shared out between train, val and test only from 3 takes; add "
                      "takes, or cut long ones into several with start/stop rows in a manifest")
    return f"{head}. Cause: {'; '.join(causes)}. Run rsmt data inspect {data_dir}" + \
        (f" --manifest {manifest}" if manifest else "") + f" for every file's problem; see {GUIDE}."
