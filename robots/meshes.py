"""The links' visual meshes, read once and cached: what the page draws for a robot.

`link_meshes(robot)` returns one trimesh per link (its URDF visuals merged, in the link frame, the
colour in `mesh.metadata["color"]`): primitives (cylinder, sphere, box) built here, mesh files
(STL, DAE, OBJ, ...) read with trimesh after `robots.packages` resolved their names (a yourdfpy
filename handler). Reading a real arm's meshes takes seconds (the Panda's DAE files: ~4 s), so the
merged result is kept twice: in this process (a robot switch in the page reuses it) and on disk as
one .npz per URDF (`cache_dir()`), keyed by the URDF's text, its mesh files' sizes and times and
the package folders, so a second `serve` starts without reading a mesh file.

A visual whose mesh file cannot be found, or that trimesh cannot read (or that holds no triangles),
is drawn as nothing: the robot still loads and runs, and `mesh_problems(robot)` names each such file
in one line (the page, `serve` and the headless commands say it once per robot, `missing_meshes_line`).
"""

from __future__ import annotations

import hashlib
import os
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import trimesh
import yourdfpy

from robots.packages import MeshNotFound, PackageResolver

CACHE_VERSION = 2  # 2: the problems (files drawn as nothing) kept beside the meshes
DEFAULT_COLOR = (175, 178, 186)  # a link whose URDF and mesh give no colour


class MeshError(ValueError):
    """A visual mesh could not be read; the message says which file and why, in one line."""


@dataclass(frozen=True)
class _Key:
    urdf: str
    packages: tuple[str, ...]


@dataclass(frozen=True)
class _Converted:
    meshes: dict[str, trimesh.Trimesh]
    problems: dict[str, str]  # mesh file name in the URDF → why it is drawn as nothing (one line)


_MEMORY: dict[tuple[_Key, str], _Converted] = {}


def cache_dir() -> Path:
    """Where converted meshes are kept: $TORQUELAB_CACHE, else $XDG_CACHE_HOME/torquelab, else
    ~/.cache/torquelab (a subfolder `meshes`)."""
    root = os.environ.get("TORQUELAB_CACHE") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache"), "torquelab"
    )
    return Path(root) / "meshes"


def link_meshes(urdf_path: str | Path, package_paths: tuple[Path, ...] = ()) -> dict[str, trimesh.Trimesh]:
    """One mesh per link with visuals (in the link frame; colour in metadata["color"]); cached, and
    the cached meshes themselves: read-only, shared by every caller. A visual whose file is missing
    or unreadable is left out (`mesh_problems` names it)."""
    return dict(_converted(urdf_path, package_paths).meshes)


def mesh_problems(urdf_path: str | Path, package_paths: tuple[Path, ...] = ()) -> dict[str, str]:
    """Mesh file name → one line saying why it is drawn as nothing (not found, not readable), for
    every visual mesh of the URDF that `link_meshes` left out; empty when all were read. Cached."""
    return dict(_converted(urdf_path, package_paths).problems)


def missing_meshes_text(problems: dict[str, str]) -> str:
    """One line for all the mesh files of a robot drawn as nothing ("" when there is none)."""
    if not problems:
        return ""
    n = len(problems)
    files = "file" if n == 1 else "files"
    return f"{n} mesh {files} drawn as nothing: " + "; ".join(problems.values())


def missing_meshes_line(robot: Any) -> str:
    """The line "NAME: N mesh files drawn as nothing: …" for a robot (`robots.load`'s) with such files, else ""."""
    text = missing_meshes_text(mesh_problems(robot.urdf_path, tuple(robot.package_paths)))
    return f"{robot.name}: {text}" if text else ""


def _converted(urdf_path: str | Path, package_paths: tuple[Path, ...]) -> _Converted:
    urdf_path = Path(urdf_path).resolve()
    resolver = PackageResolver(urdf_path, package_paths)
    urdf = yourdfpy.URDF.load(str(urdf_path), build_scene_graph=False, load_meshes=False, filename_handler=resolver)
    digest = _digest(urdf_path, urdf, resolver)
    key = (_Key(str(urdf_path), tuple(str(p) for p in package_paths)), digest)
    if key in _MEMORY:
        return _MEMORY[key]
    path = cache_dir() / f"{urdf_path.stem}-{digest[:16]}.npz"
    converted = _read_cache(path)
    if converted is None:
        converted = _convert(urdf, resolver)
        _write_cache(path, converted)
    _MEMORY[key] = _Converted(_shared(converted.meshes), converted.problems)
    return _MEMORY[key]


def _shared(meshes: dict[str, trimesh.Trimesh]) -> dict[str, trimesh.Trimesh]:
    """The meshes made read-only (their vertices and faces), so every caller can be handed the cached
    ones: a copy per call made garbage in reference cycles (a Trimesh and its caches point at each
    other) at every scene built, freed only by the collector's full passes."""
    for mesh in meshes.values():
        mesh.vertices.flags.writeable = False
        mesh.faces.flags.writeable = False
    return meshes


def _digest(urdf_path: Path, urdf: yourdfpy.URDF, resolver: PackageResolver) -> str:
    """Hash of what the converted meshes depend on: the URDF text, each mesh file's path, size and
    modification time, and the cache format."""
    h = hashlib.sha256(f"v{CACHE_VERSION}".encode())
    h.update(urdf_path.read_bytes())
    for link in urdf.robot.links:
        for visual in link.visuals:
            mesh = visual.geometry.mesh if visual.geometry is not None else None
            if mesh is None:
                continue
            try:
                path = resolver.resolve(mesh.filename)
                stat = path.stat()
            except (MeshNotFound, OSError):
                h.update(f"{mesh.filename}|missing".encode())  # drawn as nothing until it appears
                continue
            h.update(f"{path}|{stat.st_size}|{stat.st_mtime_ns}".encode())
    return h.hexdigest()


def _convert(urdf: yourdfpy.URDF, resolver: PackageResolver) -> _Converted:
    """Read and merge every link's visuals (the slow part: mesh files are parsed here); a visual
    whose file is missing or unreadable is left out and its reason kept."""
    out: dict[str, trimesh.Trimesh] = {}
    problems: dict[str, str] = {}
    for link in urdf.robot.links:
        parts, colors, areas = [], [], []
        for visual in link.visuals:
            if visual.geometry is None:
                continue
            try:
                part, color = _visual_mesh(visual.geometry, resolver)
            except (MeshError, OSError) as exc:
                name = visual.geometry.mesh.filename if visual.geometry.mesh is not None else link.name
                problems.setdefault(name, " ".join(str(exc).split()) or type(exc).__name__)
                continue
            if part is None or len(part.faces) == 0:
                continue
            if visual.origin is not None:
                part.apply_transform(np.asarray(visual.origin, dtype=float))
            material_rgba = _material_rgba(visual, urdf)
            if material_rgba is not None:
                color = material_rgba
            parts.append(part)
            colors.append(color)
            areas.append(float(part.area))
        if not parts:
            continue
        whole: Any = trimesh.util.concatenate(parts) if len(parts) > 1 else parts[0]
        merged = trimesh.Trimesh(whole.vertices, whole.faces, process=True)  # shared vertices merged
        known = [(a, c) for a, c in zip(areas, colors, strict=True) if c is not None]
        merged.metadata["color"] = tuple(max(known)[1]) if known else DEFAULT_COLOR
        out[link.name] = merged
    return _Converted(out, problems)


def _material_rgba(visual, urdf: yourdfpy.URDF) -> tuple[int, int, int] | None:
    """The URDF material colour of a visual (inline, or by name from the robot's materials)."""
    material = visual.material
    if material is None:
        return None
    color = material.color
    if color is None and material.name:
        named = next((m for m in urdf.robot.materials if m.name == material.name), None)
        color = named.color if named is not None else None
    if color is None or color.rgba is None:
        return None
    rgba = np.asarray(color.rgba, dtype=float)
    r, g, b = (round(255 * float(np.clip(c, 0, 1))) for c in rgba[:3])
    return (r, g, b)


def _visual_mesh(geometry, resolver: PackageResolver) -> tuple[trimesh.Trimesh | None, tuple[int, int, int] | None]:
    """(mesh in the visual's frame, its colour from the file or None) of one URDF visual geometry."""
    if geometry.cylinder is not None:
        mesh = trimesh.creation.cylinder(radius=geometry.cylinder.radius, height=geometry.cylinder.length, sections=24)
        return mesh, None
    if geometry.sphere is not None:
        return trimesh.creation.icosphere(subdivisions=2, radius=geometry.sphere.radius), None
    if geometry.box is not None:
        return trimesh.creation.box(extents=np.asarray(geometry.box.size, dtype=float)), None
    if geometry.mesh is None:
        return None, None
    try:
        path = resolver.resolve(geometry.mesh.filename)
    except MeshNotFound as exc:
        raise MeshError(str(exc)) from None
    mesh, color = read_mesh_file(path, geometry.mesh.filename)
    if geometry.mesh.scale is not None:
        mesh.apply_scale(np.asarray(geometry.mesh.scale, dtype=float))
    return mesh, color


def read_mesh_file(path: Path, name: str = "") -> tuple[trimesh.Trimesh, tuple[int, int, int] | None]:
    """(the file's triangles as one mesh, the colour of its largest part or None); MeshError in one
    line when trimesh cannot read it or it holds no triangles."""
    label = name or str(path)
    suffix = path.suffix.lower().lstrip(".")
    if suffix not in trimesh.available_formats():
        raise MeshError(f"mesh {label}: trimesh cannot read .{suffix} files ({path})")
    try:
        scene = trimesh.load(str(path), force="scene")
    except Exception as exc:  # trimesh raises many types on a corrupt file
        reason = " ".join(str(exc).split()) or type(exc).__name__
        raise MeshError(f"mesh {label} is not a readable mesh ({path}): {reason}") from None
    parts: list[trimesh.Trimesh] = []
    best: tuple[float, tuple[int, int, int] | None] = (0.0, None)
    for geometry in scene.dump() if hasattr(scene, "dump") else []:
        if not isinstance(geometry, trimesh.Trimesh) or len(geometry.faces) == 0:
            continue
        parts.append(geometry)
        color = _file_color(geometry)
        if color is not None and geometry.area > best[0]:
            best = (float(geometry.area), color)
    if not parts:
        raise MeshError(f"mesh {label} holds no triangles ({path})")
    mesh: Any = trimesh.util.concatenate(parts) if len(parts) > 1 else parts[0]
    return trimesh.Trimesh(mesh.vertices, mesh.faces, process=False), best[1]


def _file_color(mesh: trimesh.Trimesh) -> tuple[int, int, int] | None:
    visual = mesh.visual
    try:
        if isinstance(visual, trimesh.visual.TextureVisuals) and visual.material is not None:
            rgba = np.asarray(visual.material.main_color, dtype=float)
        elif isinstance(visual, trimesh.visual.ColorVisuals) and visual.kind is not None:
            rgba = np.asarray(visual.main_color, dtype=float)
        else:
            return None
    except (AttributeError, ValueError):
        return None
    return (int(rgba[0]), int(rgba[1]), int(rgba[2]))


def _read_cache(path: Path) -> _Converted | None:
    """The meshes and problems of a cache file, or None (absent or unreadable: it is rebuilt)."""
    try:
        with np.load(path, allow_pickle=False) as data:
            names = [str(n) for n in data["names"]]
            out = {}
            for i, name in enumerate(names):
                mesh = trimesh.Trimesh(data[f"v{i}"], data[f"f{i}"], process=False)
                mesh.metadata["color"] = tuple(int(c) for c in data[f"c{i}"])
                out[name] = mesh
            files, reasons = (str(f) for f in data["problem_files"]), (str(r) for r in data["problems"])
            problems = dict(zip(files, reasons, strict=True))
            return _Converted(out, problems)
    except (OSError, KeyError, ValueError):
        return None


def _write_cache(path: Path, converted: _Converted) -> None:
    """Store the meshes (float32 vertices, int32 faces) and problems; a cache folder that cannot be
    written is skipped."""
    meshes = converted.meshes
    arrays: dict[str, np.ndarray] = {
        "names": np.array(list(meshes), dtype=str),
        "problem_files": np.array(list(converted.problems), dtype=str),
        "problems": np.array(list(converted.problems.values()), dtype=str),
    }
    for i, mesh in enumerate(meshes.values()):
        arrays[f"v{i}"] = np.asarray(mesh.vertices, dtype=np.float32)
        arrays[f"f{i}"] = np.asarray(mesh.faces, dtype=np.int32)
        arrays[f"c{i}"] = np.asarray(mesh.metadata["color"], dtype=np.int32)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(f".{os.getpid()}.tmp.npz")
        np.savez(tmp, **arrays)  # type: ignore[arg-type]
        tmp.replace(path)
    except OSError:
        pass


def warm_in_background(names: tuple[str, ...]) -> subprocess.Popen | None:
    """Convert the meshes of the robots `names` into the disk cache in a niced child process (the
    app's loop keeps its core; a robot switch in the page then reads the cache). None when there is
    nothing to do or no child could be started."""
    if not names:
        return None
    try:
        return subprocess.Popen(
            [sys.executable, "-m", "robots.meshes", *names],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            preexec_fn=(lambda: os.nice(10)) if hasattr(os, "nice") else None,
        )
    except OSError:
        return None


def main(argv: list[str]) -> int:
    """`python -m robots.meshes NAME...`: fill the disk cache for these robots (errors skipped)."""
    import robots

    for name in argv:
        try:
            robot = robots.load(name)
            link_meshes(robot.urdf_path, robot.package_paths)
        except (robots.RobotLoadError, MeshError, OSError):
            continue
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
