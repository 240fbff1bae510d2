"""Which code made a result: a hash of the installed torquelab sources, recorded by sweeps and experiments."""

from __future__ import annotations

import hashlib
from functools import lru_cache
from pathlib import Path

import app


@lru_cache(maxsize=1)
def code_version() -> str:
    """Hash of the installed torquelab sources (app/, control/, robots/): which code made a sweep cell
    or an experiment run."""
    root = Path(app.__file__).resolve().parent.parent
    h = hashlib.sha256()
    for package in ("app", "control", "robots"):
        for path in sorted((root / package).rglob("*")):
            if path.suffix in (".py", ".toml", ".urdf") and path.is_file():
                h.update(str(path.relative_to(root)).encode())
                h.update(path.read_bytes())
    return h.hexdigest()[:12]
