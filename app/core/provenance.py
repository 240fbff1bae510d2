"""Which code made a result: the git commit of the checkout (with "+dirty" when its tree differs from
the commit) and, beside it, a hash of the installed torquelab sources; recorded by sweeps and
experiments with their data and printed by their reports."""

from __future__ import annotations

import hashlib
import subprocess
from functools import lru_cache
from pathlib import Path

import app

GIT_TIMEOUT_S = 10.0  # a git that does not answer in this time counts as no checkout


def _root() -> Path:
    return Path(app.__file__).resolve().parent.parent


@lru_cache(maxsize=1)
def code_version() -> str:
    """Hash of the installed torquelab sources (app/, control/, robots/): which code made a sweep cell
    or an experiment run, with or without a git checkout (a run is reused only under the same hash)."""
    root = _root()
    h = hashlib.sha256()
    for package in ("app", "control", "robots"):
        for path in sorted((root / package).rglob("*")):
            if path.suffix in (".py", ".toml", ".urdf") and path.is_file():
                h.update(str(path.relative_to(root)).encode())
                h.update(path.read_bytes())
    return h.hexdigest()[:12]


def _git(*words: str) -> str | None:
    """stdout of `git -C ROOT words…`, None when git is missing, fails or the sources are no checkout."""
    try:
        done = subprocess.run(
            ["git", "-C", str(_root()), *words], capture_output=True, text=True, timeout=GIT_TIMEOUT_S, check=False
        )
    except (OSError, subprocess.SubprocessError):
        return None
    return done.stdout if done.returncode == 0 else None


@lru_cache(maxsize=1)
def git_commit() -> str | None:
    """The commit the sources are checked out at, "+dirty" appended when the working tree differs from
    it (a tracked file changed or an untracked, not ignored file added); None without a git checkout."""
    head = _git("rev-parse", "HEAD")
    if not head or not head.strip():
        return None
    status = _git("status", "--porcelain")
    dirty = status is None or bool(status.strip())  # a status git cannot give is not a clean tree
    return head.strip()[:12] + ("+dirty" if dirty else "")


def code_record() -> dict:
    """The code identity a run records beside its data: {"commit": git_commit(), "source": code_version()}."""
    return {"commit": git_commit(), "source": code_version()}


def code_text(record: dict | str | None = None) -> str:
    """A code identity in words: "commit 5092a13c0ffe+dirty, source hash 17e9b63697e5", or "no git
    checkout, source hash …"; `record` is one `code_record` stored with a run (a bare source hash
    from older runs; None: this process's code)."""
    if record is None:
        record = code_record()
    if isinstance(record, str):
        return f"source hash {record} (commit not recorded)"
    commit, source = record.get("commit"), record.get("source", "not recorded")
    return f"commit {commit}, source hash {source}" if commit else f"no git checkout, source hash {source}"
