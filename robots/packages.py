"""Mesh file names of a URDF resolved the way ROS users expect.

`package://NAME/rest` is looked for, in order: in a folder named NAME among the URDF file's
ancestors (a description unpacked anywhere with its package folder around it), then in each
`--package-path DIR` (DIR/NAME/rest, or DIR/rest when DIR itself is named NAME), then in each
folder of the `ROS_PACKAGE_PATH` environment variable (the same two forms). `file://` URIs are
absolute paths; a plain name is relative to the URDF's folder. A file that still cannot be found
is one line naming the URI and the folders searched.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

PACKAGE_PREFIX = "package://"
FILE_PREFIX = "file://"


class MeshNotFound(FileNotFoundError):
    """A mesh URI resolved to no file; the message names the URI and the folders searched."""


def ros_package_path() -> tuple[Path, ...]:
    """The folders of ROS_PACKAGE_PATH (empty entries dropped)."""
    return tuple(Path(p) for p in os.environ.get("ROS_PACKAGE_PATH", "").split(os.pathsep) if p)


class PackageResolver:
    """Turns the mesh file names of one URDF into paths (`resolve`); usable as a yourdfpy
    `filename_handler`."""

    def __init__(self, urdf_path: Path, package_paths: Sequence[Path | str] = ()):
        self.urdf_path = Path(urdf_path).resolve()
        self.package_paths = tuple(Path(p).expanduser() for p in package_paths)

    def __call__(self, fname: str) -> str:
        """yourdfpy's filename handler protocol: the resolved path as a string."""
        return str(self.resolve(fname))

    def package_candidates(self, name: str, rest: str) -> list[Path]:
        """Every place `package://name/rest` may be, in search order."""
        out = [anc / rest for anc in self.urdf_path.parents if anc.name == name]
        for folder in (*self.package_paths, *ros_package_path()):
            out.append(folder / rest if folder.name == name else folder / name / rest)
        return out

    def resolve(self, fname: str) -> Path:
        """The file a URDF mesh name refers to; MeshNotFound (one line) when there is none."""
        if fname.startswith(PACKAGE_PREFIX):
            name, _, rest = fname[len(PACKAGE_PREFIX) :].partition("/")
            candidates = self.package_candidates(name, rest)
            for path in candidates:
                if path.is_file():
                    return path
            searched = sorted({str(_package_root(p, rest)) for p in candidates})
            where = ", ".join(searched) if searched else "no folder"
            raise MeshNotFound(
                f"mesh {fname} not found: no package {name!r} among the URDF's folders, --package-path or"
                f" ROS_PACKAGE_PATH (searched {where}); add --package-path DIR with DIR/{name} inside"
            )
        if fname.startswith(FILE_PREFIX):
            path = Path(fname[len(FILE_PREFIX) :])
        else:
            path = Path(fname)
            if not path.is_absolute():
                path = self.urdf_path.parent / path
        if not path.is_file():
            raise MeshNotFound(f"mesh {fname} not found (looked at {path})")
        return path


def _package_root(candidate: Path, rest: str) -> Path:
    """The package folder of a candidate path (the candidate without `rest`)."""
    depth = len(Path(rest).parts)
    return candidate.parents[depth - 1] if depth else candidate
