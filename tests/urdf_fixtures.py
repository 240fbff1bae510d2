"""Small URDFs of our own for the loader tests: a 7-DOF arm with a two-finger gripper, two such
arms on one torso, and mesh references by `package://` in a chosen folder layout."""

from __future__ import annotations

from pathlib import Path

import trimesh

AXES = ("0 0 1", "0 1 0", "0 0 1", "0 1 0", "0 0 1", "0 1 0", "0 0 1")


def _inertial(mass: float) -> str:
    return (
        f'<inertial><origin xyz="0.01 0.005 0.05"/><mass value="{mass}"/>'
        f'<inertia ixx="{0.01 * mass}" ixy="0.0001" ixz="0" iyy="{0.012 * mass}" iyz="0"'
        f' izz="{0.005 * mass}"/></inertial>'
    )


def _visual(mesh: str | None) -> str:
    if mesh is None:
        return '<visual><geometry><cylinder radius="0.04" length="0.1"/></geometry></visual>'
    return f'<visual><geometry><mesh filename="{mesh}"/></geometry></visual>'


def arm(prefix: str, parent: str, origin: str = "0 0 0", mesh: str | None = None, gripper: bool = True) -> str:
    """Links and joints of one 7-DOF arm named `prefix`_link0..7 under `parent` (plus a fixed
    flange and, with `gripper`, two prismatic fingers)."""
    parts = [f'<link name="{prefix}_link0">{_inertial(1.0)}{_visual(mesh)}</link>']
    parts.append(
        f'<joint name="{prefix}_mount" type="fixed"><parent link="{parent}"/><child link="{prefix}_link0"/>'
        f'<origin xyz="{origin}"/></joint>'
    )
    for i in range(1, 8):
        parts.append(f'<link name="{prefix}_link{i}">{_inertial(2.0 - 0.2 * i)}{_visual(mesh)}</link>')
        parts.append(
            f'<joint name="{prefix}_joint{i}" type="revolute"><parent link="{prefix}_link{i - 1}"/>'
            f'<child link="{prefix}_link{i}"/><origin xyz="0 0 {0.1 if i > 1 else 0.15}"/><axis xyz="{AXES[i - 1]}"/>'
            f'<limit lower="-2.5" upper="2.5" effort="{80 if i < 5 else 12}" velocity="2.0"/></joint>'
        )
    parts.append(f'<link name="{prefix}_flange"/>')
    parts.append(
        f'<joint name="{prefix}_flange_joint" type="fixed"><parent link="{prefix}_link7"/>'
        f'<child link="{prefix}_flange"/><origin xyz="0 0 0.05"/></joint>'
    )
    if gripper:
        for side, sign in (("left", 1), ("right", -1)):
            parts.append(f'<link name="{prefix}_{side}_finger">{_inertial(0.1)}</link>')
            parts.append(
                f'<joint name="{prefix}_{side}_finger_joint" type="prismatic"><parent link="{prefix}_link7"/>'
                f'<child link="{prefix}_{side}_finger"/><origin xyz="0 0 0.06"/><axis xyz="0 {sign} 0"/>'
                f'<limit lower="0" upper="0.04" effort="20" velocity="0.2"/></joint>'
            )
    return "\n".join(parts)


def robot(name: str, body: str, root: str = "world_base") -> str:
    """A URDF text with a root link `root` and the given links and joints."""
    return f'<?xml version="1.0"?>\n<robot name="{name}">\n<link name="{root}"/>\n{body}\n</robot>\n'


def gripper_arm(mesh: str | None = None) -> str:
    """One 7-DOF arm with a gripper on a base link."""
    return robot("gripper_arm", arm("a", "world_base", mesh=mesh))


def two_arms() -> str:
    """A torso (with one revolute waist joint) carrying two 7-DOF arms with grippers."""
    torso = (
        f'<link name="torso">{_inertial(5.0)}</link>'
        '<joint name="waist" type="revolute"><parent link="world_base"/><child link="torso"/>'
        '<origin xyz="0 0 0.5"/><axis xyz="0 0 1"/><limit lower="-1" upper="1" effort="100" velocity="1"/></joint>'
    )
    return robot("two_arms", torso + arm("left", "torso", "0 0.2 0.3") + arm("right", "torso", "0 -0.2 0.3"))


def write(path: Path, text: str) -> Path:
    """Write a URDF text (folders created) and return its path."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def box_mesh(path: Path) -> Path:
    """A small box mesh file (STL/OBJ by suffix)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    trimesh.creation.box(extents=(0.05, 0.05, 0.1)).export(path)
    return path


def gripper_arm_meshes(meshes: dict[str, str]) -> str:
    """`gripper_arm()` with the visual of each named link a mesh file (link name → file name)."""
    text = gripper_arm()
    for link, mesh in meshes.items():
        start = text.index(f'<link name="{link}">')
        at = text.index(_visual(None), start)
        text = text[:at] + _visual(mesh) + text[at + len(_visual(None)) :]
    return text
