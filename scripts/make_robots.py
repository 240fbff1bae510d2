"""Write the shipped robot URDFs (robots/*.urdf) from the manufacturers' public numbers.

Run `python scripts/make_robots.py` after changing a number; the URDFs are committed so nothing
is generated at install or run time. Geometry is primitive (cylinders and spheres) sized to the
links: one housing cylinder on each joint axis and one cylinder along each link to the next joint.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

PI = math.pi
ROBOTS_DIR = Path(__file__).resolve().parent.parent / "robots"

# joint: (name, parent, child, xyz, rpy, axis, lower, upper, velocity, effort)
RIZON_JOINTS = [
    ("joint1", "base_link", "link1", (0, 0, 0.155), (0, 0, -PI), "z", -2.8798, 2.8798, 2.0944, 123),
    ("joint2", "link1", "link2", (0, 0.03, 0.21), (0, 0, 0), "y", -2.3562, 2.3562, 2.0944, 123),
    ("joint3", "link2", "link3", (0, 0.035, 0.205), (0, 0, 0), "z", -3.0543, 3.0543, 2.4435, 64),
    ("joint4", "link3", "link4", (-0.02, -0.03, 0.19), (0, 0, -PI), "y", -1.9548, 2.7751, 2.4435, 64),
    ("joint5", "link4", "link5", (-0.02, 0.025, 0.195), (0, 0, -PI), "z", -3.0543, 3.0543, 4.8869, 39),
    ("joint6", "link5", "link6", (0, 0.03, 0.19), (0, 0, 0), "y", -1.4835, 4.6251, 4.8869, 39),
    ("joint7", "link6", "link7", (-0.015, 0.073, 0.11), (0, -PI / 2, 0), "z", -3.0543, 3.0543, 4.8869, 39),
]
RIZON_FIXED = [("flange_joint", "link7", "flange", (0, 0, 0.124), (0, 0, -PI))]
# link: (mass, com, (ixx, iyy, izz, ixy, ixz, iyz))
RIZON_LINKS = {
    "base_link": (3.8, (0, 0, 0.09), (0.02, 0.02, 0.01, 0, 0, 0)),  # inertia not published: a 0.1 m cylinder
    "link1": (3.6, (0, 0, 0.15), (0.03, 0.03, 0.01, 0, 0, 0)),
    "link2": (2.7, (0, 0.04, 0.1), (0.02, 0.02, 0.004, 0, 0, -0.0003)),
    "link3": (2.4, (-0.01, 0, 0.14), (0.01, 0.01, 0.004, 0, -0.001, -0.0007)),
    "link4": (2.4, (-0.01, 0.03, 0.1), (0.02, 0.02, 0.003, 0, -0.002, -0.001)),
    "link5": (2.3, (0, 0, 0.14), (0.01, 0.01, 0.004, 0, 0, 0.001)),
    "link6": (2.2, (0.02, 0.06, 0.07), (0.01, 0.01, 0.004, 0, -0.001, 0.002)),
    "link7": (1.4, (0, 0, 0.05), (0.001, 0.001, 0.001, 0, 0, 0)),
}
RIZON_RADII = {
    "base_link": 0.07,
    "link1": 0.065,
    "link2": 0.06,
    "link3": 0.055,
    "link4": 0.05,
    "link5": 0.045,
    "link6": 0.045,
    "link7": 0.04,
    "flange": 0.035,
}

_G3_BIG, _G3_SMALL = (1.3963, 39), (1.2218, 9)
_ENDLESS = 2 * PI  # endless joints: revolute with +-2 pi in the URDF, marked endless in the sidecar
GEN3_JOINTS = [
    ("joint_1", "base_link", "shoulder_link", (0, 0, 0.15643), (PI, 0, 0), "z", -_ENDLESS, _ENDLESS, *_G3_BIG),
    (
        "joint_2",
        "shoulder_link",
        "half_arm_1_link",
        (0, 0.005375, -0.12838),
        (PI / 2, 0, 0),
        "z",
        -2.24,
        2.24,
        *_G3_BIG,
    ),
    (
        "joint_3",
        "half_arm_1_link",
        "half_arm_2_link",
        (0, -0.21038, -0.006375),
        (-PI / 2, 0, 0),
        "z",
        -_ENDLESS,
        _ENDLESS,
        *_G3_BIG,
    ),
    ("joint_4", "half_arm_2_link", "forearm_link", (0, 0.006375, -0.21038), (PI / 2, 0, 0), "z", -2.57, 2.57, *_G3_BIG),
    (
        "joint_5",
        "forearm_link",
        "spherical_wrist_1_link",
        (0, -0.20843, -0.006375),
        (-PI / 2, 0, 0),
        "z",
        -_ENDLESS,
        _ENDLESS,
        *_G3_SMALL,
    ),
    (
        "joint_6",
        "spherical_wrist_1_link",
        "spherical_wrist_2_link",
        (0, 0.00017505, -0.10593),
        (PI / 2, 0, 0),
        "z",
        -2.09,
        2.09,
        *_G3_SMALL,
    ),
    (
        "joint_7",
        "spherical_wrist_2_link",
        "bracelet_link",
        (0, -0.10593, -0.00017505),
        (-PI / 2, 0, 0),
        "z",
        -_ENDLESS,
        _ENDLESS,
        *_G3_SMALL,
    ),
]
GEN3_FIXED = [("end_effector", "bracelet_link", "end_effector_link", (0, 0, -0.061525), (PI, 0, 0))]
GEN3_LINKS = {
    "base_link": (1.697, (-0.000648, -0.000166, 0.084487), (0.004622, 0.004495, 0.002079, 0, 0, 0)),
    "shoulder_link": (1.3773, (-2.3e-5, -0.010364, -0.07336), (0.00457, 0.004831, 0.001409, 0, 0, 0.000448)),
    "half_arm_1_link": (1.1636, (-4.4e-5, -0.09958, -0.013278), (0.011088, 0.001072, 0.011255, 0, 0, -0.000691)),
    "half_arm_2_link": (1.1636, (-4.4e-5, -0.006641, -0.117892), (0.010932, 0.011127, 0.001043, 0, 0, 0.000606)),
    "forearm_link": (0.9302, (-1.8e-5, -0.075478, -0.015006), (0.008147, 0.000631, 0.008316, 0, 0, -0.0005)),
    "spherical_wrist_1_link": (0.6781, (1e-6, -0.009432, -0.063883), (0.001596, 0.001607, 0.000399, 0, 0, 0.000256)),
    "spherical_wrist_2_link": (0.6781, (1e-6, -0.045483, -0.00965), (0.001641, 0.00041, 0.001641, 0, 0, -0.000278)),
    "bracelet_link": (0.5, (0.000281, 0.011402, -0.029798), (0.000587, 0.000369, 0.000609, 0, 0, -0.000118)),
}
GEN3_RADII = {
    "base_link": 0.05,
    "shoulder_link": 0.05,
    "half_arm_1_link": 0.045,
    "half_arm_2_link": 0.045,
    "forearm_link": 0.04,
    "spherical_wrist_1_link": 0.035,
    "spherical_wrist_2_link": 0.035,
    "bracelet_link": 0.035,
    "end_effector_link": 0.02,
}


def _rpy_z_to(direction: np.ndarray) -> tuple[float, float, float]:
    """Roll-pitch-yaw of a rotation that takes +z onto `direction` (URDF fixed-axis XYZ convention)."""
    d = direction / np.linalg.norm(direction)
    pitch = math.atan2(math.hypot(d[0], d[1]), d[2])
    yaw = math.atan2(d[1], d[0])
    # R = Rz(yaw) Ry(pitch) maps z to d; as URDF rpy: roll=0, pitch, yaw
    return (0.0, pitch, yaw)


def _f(v) -> str:
    return " ".join(f"{float(x):.9g}" for x in v)


def _geometry(link: str, joints, fixed, radii: dict) -> list[str]:
    """Visual + collision blocks for one link: a housing on the child joint axis and a cylinder to it."""
    out: list[str] = []
    r = radii.get(link, 0.04)
    children = [j for j in joints if j[1] == link] + [f for f in fixed if f[1] == link]
    shapes: list[tuple[str, tuple, tuple]] = [(f'<sphere radius="{r:.4g}"/>', (0, 0, 0), (0, 0, 0))]
    for child in children:
        xyz = np.array(child[3], dtype=float)
        length = float(np.linalg.norm(xyz))
        if length > 1e-6:
            shapes.append((f'<cylinder radius="{r:.4g}" length="{length:.6g}"/>', tuple(xyz / 2), _rpy_z_to(xyz)))
        if len(child) > 5:  # a moving joint: a housing along its axis, expressed in this link's frame
            axis = Rotation.from_euler("xyz", child[4]).apply([0, 0, 1] if child[5] == "z" else [0, 1, 0])
            shapes.append((f'<cylinder radius="{r * 1.05:.4g}" length="{2.2 * r:.4g}"/>', tuple(xyz), _rpy_z_to(axis)))
    for tag in ("visual", "collision"):
        for geom, xyz, rpy in shapes:
            out.append(f'    <{tag}><origin xyz="{_f(xyz)}" rpy="{_f(rpy)}"/><geometry>{geom}</geometry></{tag}>')
    return out


def write_urdf(name: str, joints, fixed, links: dict, radii: dict, tool: tuple[str, float] | None) -> str:
    lines = [
        '<?xml version="1.0"?>',
        f"<!-- {name}: generated by scripts/make_robots.py from published kinematic and inertial data -->",
        f'<robot name="{name}">',
        '  <mujoco><compiler fusestatic="false" discardvisual="false" inertiafromgeom="false"/></mujoco>',
    ]
    all_links = list(links) + [f[2] for f in fixed]
    for link in all_links:
        lines.append(f'  <link name="{link}">')
        if link in links:
            m, com, (ixx, iyy, izz, ixy, ixz, iyz) = links[link]
            lines.append(
                f'    <inertial><origin xyz="{_f(com)}" rpy="0 0 0"/><mass value="{m}"/>'
                f'<inertia ixx="{ixx}" ixy="{ixy}" ixz="{ixz}" iyy="{iyy}" iyz="{iyz}" izz="{izz}"/></inertial>'
            )
        lines += _geometry(link, joints, fixed, radii)
        if tool is not None and link == tool[0]:
            length = tool[1]
            for tag in ("visual", "collision"):
                lines.append(
                    f'    <{tag}><origin xyz="0 0 {length / 2:.6g}" rpy="0 0 0"/>'
                    f'<geometry><cylinder radius="0.015" length="{length:.6g}"/></geometry></{tag}>'
                )
        lines.append("  </link>")
    for name_, parent, child, xyz, rpy, axis, lo, hi, vel, eff in joints:
        ax = "0 0 1" if axis == "z" else "0 1 0"
        lines.append(
            f'  <joint name="{name_}" type="revolute"><parent link="{parent}"/><child link="{child}"/>'
            f'<origin xyz="{_f(xyz)}" rpy="{_f(rpy)}"/><axis xyz="{ax}"/>'
            f'<limit lower="{lo}" upper="{hi}" velocity="{vel}" effort="{eff}"/></joint>'
        )
    for name_, parent, child, xyz, rpy in fixed:
        lines.append(
            f'  <joint name="{name_}" type="fixed"><parent link="{parent}"/><child link="{child}"/>'
            f'<origin xyz="{_f(xyz)}" rpy="{_f(rpy)}"/></joint>'
        )
    lines.append("</robot>")
    return "\n".join(lines) + "\n"


def main() -> None:
    (ROBOTS_DIR / "rizon4s.urdf").write_text(
        write_urdf("rizon4s", RIZON_JOINTS, RIZON_FIXED, RIZON_LINKS, RIZON_RADII, tool=("flange", 0.10))
    )
    (ROBOTS_DIR / "gen3.urdf").write_text(
        write_urdf("gen3", GEN3_JOINTS, GEN3_FIXED, GEN3_LINKS, GEN3_RADII, tool=None)
    )


if __name__ == "__main__":
    main()
