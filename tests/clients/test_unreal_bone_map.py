"""The Unreal bone map (``clients/unreal/RsmtLink/Retargeting/rsmt-to-mannequin.json``) against the rig that
``rsmt rig export`` writes: every joint of the model mapped once, chains that run along the rig's parents and
cover it, chain ends that are the mapped bones, and the table of docs/retargeting.md saying the same."""

from __future__ import annotations

import json
import re

from tests.clients.helpers import UNREAL

REPO = UNREAL.parents[2]
MAP = json.loads((UNREAL / "Retargeting" / "rsmt-to-mannequin.json").read_text())
RIG = json.loads((REPO / "clients" / "rig" / "rsmt-default-rig.tpose.json").read_text())
NAMES = [j["name"] for j in RIG["joints"]]
PARENT = {j["name"]: (NAMES[j["parent"]] if j["parent"] >= 0 else None) for j in RIG["joints"]}


def path_down(start: str, end: str) -> list[str]:
    """The joints from ``start`` to its descendant ``end`` (both included), or [] when ``end`` is not below it."""
    walk: list[str] = []
    at: str | None = end
    while at is not None:
        walk.append(at)
        if at == start:
            return walk[::-1]
        at = PARENT[at]
    return []


def test_every_model_joint_is_mapped_once_to_its_own_bones() -> None:
    assert sorted(MAP["bones"]) == sorted(NAMES)
    targets = [b for bones in MAP["bones"].values() for b in bones]
    assert all(targets) and len(targets) == len(set(targets))
    root = next(j["name"] for j in RIG["joints"] if j["parent"] < 0)
    assert MAP["retarget_root"] == {"source": root, "target": MAP["bones"][root][0]}


def test_chains_follow_the_rig_cover_it_and_end_on_the_mapped_bones() -> None:
    covered = [MAP["retarget_root"]["source"]]
    for chain in MAP["chains"]:
        start, end = chain["source"]
        joints = path_down(start, end)
        assert joints, (chain["name"], "the end is not below the start on the rig")
        covered += joints
        assert chain["target"] == [MAP["bones"][start][0], MAP["bones"][end][-1]], chain
    assert sorted(covered) == sorted(NAMES)  # each joint in one chain (or the root), none left out
    assert len({c["name"] for c in MAP["chains"]}) == len(MAP["chains"])


def test_the_retargeting_guide_table_says_the_same() -> None:
    text = (REPO / "docs" / "retargeting.md").read_text()
    section = text[text.index("## 2. Joint names"):text.index("## 3.")]
    table = section[:section.index("\n\n", section.index("| model joint"))]  # the first table: the Mannequin's bones
    seen = {}
    for row in re.findall(r"^\| ([A-Z][^|]*?) \| [^|]* \| ([^|]*?) \| [^|]* \|$", table, flags=re.M):
        model, mannequin = row
        if " / " in model:  # "Shoulder_L / _R" with "clavicle_l / clavicle_r"
            left, right = (p.strip() for p in model.split("/"))
            bones = [p.strip() for p in mannequin.split("/")]
            seen[left], seen[left[:-2] + right] = [bones[0]], [bones[1]]
        else:
            seen[model.strip()] = [b.strip() for b in mannequin.split(",")]
    assert seen == MAP["bones"]
