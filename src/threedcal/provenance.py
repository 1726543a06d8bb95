"""Digests of the library source a stage depends on, passed to Snakemake as `params`.

Snakemake reruns a job when its params change, so a digest of the code (and profiles) that a stage
imports makes "the library changed" a rerun reason — and only for the stages that use that code.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

PACKAGE_ROOT = Path(__file__).resolve().parent
# Modules every stage reads (config, profiles, errors); a change to them reruns everything.
CORE = ("__init__.py", "config.py", "errors.py", "profiles", "schemas")


def _files(part: str, root: Path) -> list[Path]:
    path = root / part
    if path.is_dir():
        return sorted(p for p in path.rglob("*") if p.suffix in {".py", ".yaml"} and p.is_file())
    if path.suffix:
        return [path] if path.is_file() else []
    module = path.with_suffix(".py")
    if module.is_file():
        return [module]
    raise ValueError(f"threedcal has no module or package {part!r}")


def source_digest(*parts: str, root: Path = PACKAGE_ROOT) -> str:
    """sha256 (16 hex) of the listed threedcal modules/packages plus the core, e.g. ("sim", "collect")."""
    digest = hashlib.sha256()
    for part in sorted(set(CORE) | set(parts)):
        for path in _files(part, root):
            digest.update(str(path.relative_to(root)).encode())
            digest.update(b"\0")
            digest.update(path.read_bytes())
    return digest.hexdigest()[:16]
