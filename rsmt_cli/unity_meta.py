"""Unity ``.meta`` files for a package folder, with GUIDs derived from the package name and the path.

Unity gives every asset (file or folder) a ``.meta`` holding its GUID; a package without them is read-only in
the editor and gets fresh, random GUIDs in every project, which breaks references to its assets. Deriving the
GUID from ``package name + path`` keeps it stable across machines and runs. Folders ending in ``~`` and names
starting with ``.`` are ignored by Unity and get none.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

_IMPORTERS = {
    ".cs": "MonoImporter:\n  externalObjects: {}\n  serializedVersion: 2\n  defaultReferences: []\n  executionOrder: 0\n"
           "  icon: {instanceID: 0}\n",
    ".asmdef": "AssemblyDefinitionImporter:\n  externalObjects: {}\n",
    ".md": "TextScriptImporter:\n  externalObjects: {}\n",
    ".txt": "TextScriptImporter:\n  externalObjects: {}\n",
    ".bvh": "TextScriptImporter:\n  externalObjects: {}\n",
    ".json": "TextScriptImporter:\n  externalObjects: {}\n",
}
_TAIL = "  userData: \n  assetBundleName: \n  assetBundleVariant: \n"


def ignored(rel: Path) -> bool:
    """Whether Unity skips this path: a part ending in ``~`` or starting with ``.``."""
    return any(part.endswith("~") or part.startswith(".") for part in rel.parts)


def guid(package: str, rel: Path) -> str:
    """32 hex digits from ``package/relative/path`` (POSIX separators)."""
    return hashlib.md5(f"{package}/{rel.as_posix()}".encode()).hexdigest()


def meta_text(package: str, root: Path, rel: Path) -> str:
    head = f"fileFormatVersion: 2\nguid: {guid(package, rel)}\n"
    path = root / rel
    if path.is_dir():
        return head + "folderAsset: yes\nDefaultImporter:\n  externalObjects: {}\n" + _TAIL
    if rel.as_posix() == "package.json":
        return head + "PackageManifestImporter:\n  externalObjects: {}\n" + _TAIL
    importer = _IMPORTERS.get(path.suffix.lower(), "DefaultImporter:\n  externalObjects: {}\n")
    return head + importer + _TAIL


def assets(root: Path) -> list[Path]:
    """Every file and folder under ``root`` that Unity imports (relative paths, sorted), ``.meta`` files excluded."""
    out = []
    for path in sorted(root.rglob("*")):
        rel = path.relative_to(root)
        if ignored(rel) or path.suffix == ".meta":
            continue
        out.append(rel)
    return out


def write_metas(root: Path, package: str, check: bool = False) -> list[str]:
    """Write a ``.meta`` next to every asset; remove ``.meta`` files whose asset is gone.

    With ``check``, write nothing and return the paths that are missing, stale or orphaned instead.
    """
    problems = []
    wanted = set()
    for rel in assets(root):
        meta = root / (rel.as_posix() + ".meta")
        wanted.add(meta)
        text = meta_text(package, root, rel)
        if not meta.is_file() or meta.read_text() != text:
            problems.append(str(meta.relative_to(root)))
            if not check:
                meta.write_text(text)
    for meta in sorted(root.rglob("*.meta")):
        if meta not in wanted and not ignored(meta.relative_to(root)):
            problems.append(str(meta.relative_to(root)))
            if not check:
                meta.unlink()
    return problems
