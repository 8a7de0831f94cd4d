"""The ``rsmt rig`` commands: the model's rig as engine assets, and the Unity package's ``.meta`` files."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

DEFAULT_SKELETON = Path(__file__).resolve().parents[1] / "model" / "default_bundle" / "skeleton.json"


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("rig", help="engine assets of the model's rig (BVH, glTF, T-pose) and Unity .meta files")
    sub = p.add_subparsers(dest="rig_command", required=True, metavar="ACTION")
    e = sub.add_parser("export", help="write STEM.bvh, STEM.gltf and STEM.tpose.json for a skeleton",
                       description="The skeleton in a T-pose (BVH frame 0 and the glTF bind pose) plus a one-second "
                                   "motion (arms lowering), for importing the model's rig into Unity, Unreal or Blender.")
    e.add_argument("--skeleton", type=Path, default=DEFAULT_SKELETON,
                   help="skeleton.json of a bundle (default: the default model's)")
    e.add_argument("--out", type=Path, required=True, help="output folder (e.g. clients/rig)")
    e.add_argument("--stem", default="rsmt-default-rig", help="file name stem")
    e.add_argument("--fps", type=float, default=30.0, help="frame rate of the sample motion")
    e.add_argument("--unity-package", type=Path,
                   help="also copy STEM.tpose.json into PACKAGE/Rig/ (the Unity helpers read it as a TextAsset)")
    e.set_defaults(func=_export)
    m = sub.add_parser("unity-meta", help="write deterministic .meta files for every asset of a Unity package",
                       description="GUIDs are an MD5 of 'package-name/relative/path'; folders ending in ~ are skipped.")
    m.add_argument("--package", type=Path, required=True, help="the package folder (with package.json)")
    m.add_argument("--check", action="store_true", help="write nothing; exit 1 listing missing or stale .meta files")
    m.set_defaults(func=_unity_meta)


def _export(args: argparse.Namespace) -> int:
    from rsmt_cli.rig_asset import export

    files = export(args.skeleton, args.out, args.stem, args.fps)
    if args.unity_package is not None:
        rig = args.unity_package / "Rig"
        rig.mkdir(exist_ok=True)
        files["unity_tpose"] = rig / files["tpose"].name
        files["unity_tpose"].write_bytes(files["tpose"].read_bytes())
    print(json.dumps({k: str(v) for k, v in files.items()}, indent=1))
    return 0


def _unity_meta(args: argparse.Namespace) -> int:
    from rsmt_cli.unity_meta import write_metas

    name = json.loads((args.package / "package.json").read_text())["name"]
    problems = write_metas(args.package, name, check=args.check)
    print(json.dumps({"package": name, "check": args.check, "changed" if not args.check else "stale": problems}, indent=1))
    return 1 if args.check and problems else 0
