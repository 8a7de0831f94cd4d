"""The ``rsmt profile`` command group: ``rsmt profile guess`` writes a starting skeleton profile."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from model.data.takes import find_bvh_files


def register(subparsers: argparse._SubParsersAction) -> None:
    profile = subparsers.add_parser("profile", help="skeleton profiles: which joints play which role on a rig",
                                    description="Write and check skeleton profiles (docs/your-rig.md).")
    sub = profile.add_subparsers(dest="profile_command", required=True, metavar="SUBCOMMAND")
    guess = sub.add_parser(
        "guess", help="guess a profile from a rig's joint names",
        description="Read one BVH take (the first under DIR, or DIR itself when it is a file) and write a starting "
                    "profile: root, head, feet, the facing hips and shoulders, mirror rules and joints to drop "
                    "(fingers; helper joints with no offset and no rotation). What it cannot decide is listed on "
                    "stderr and the exit status is 1; check the result with rsmt data inspect DIR --profile FILE.")
    guess.add_argument("folder", type=Path, metavar="DIR", help="folder of BVH takes, or one BVH file")
    guess.add_argument("--out", type=Path, metavar="FILE", help="write the profile here (default: print it)")
    guess.add_argument("--name", help="the profile's name (default: the folder's name)")
    guess.set_defaults(func=guess_command)


def guess_command(args: argparse.Namespace) -> int:
    from model.motion.bvh import BvhDocument
    from model.motion.profile_guess import guess_profile

    folder: Path = args.folder
    if folder.is_file():
        take = folder
    else:
        files = find_bvh_files(folder) if folder.is_dir() else []
        if not files:
            raise FileNotFoundError(f"no BVH file under {folder}")
        take = files[0]
    name = args.name or (take.parent.name if folder.is_file() else folder.resolve().name) or "my-rig"
    guess = guess_profile(BvhDocument.read(take), name=name)
    text = json.dumps(guess.profile, indent=1) + "\n"
    print(f"profile guessed from {take}", file=sys.stderr)
    for note in guess.notes:
        print(f"note: {note}", file=sys.stderr)
    for item in guess.undecided:
        print(f"undecided: {item}", file=sys.stderr)
    if args.out is not None:
        args.out.write_text(text)
        print(f"wrote {args.out}", file=sys.stderr)
    else:
        sys.stdout.write(text)
    return 1 if guess.undecided else 0
