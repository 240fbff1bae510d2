"""Which chain of a URDF is the arm: the joint tree, the base and tip, and the joints locked.

A real URDF holds more than a 7-DOF arm: fingers, a second arm, a torso, a mobile base. The arm is
the chain of joints between a base link and a tip link; every other movable joint is locked at a
stated position (its zero clipped into its limits, or a value the sidecar gives). Defaults: the
base is the URDF's root; the tip ends the only chain of 7 revolute joints from the base (extended
along fixed joints while that path does not branch). Several such chains, or none, is a one-line
refusal that lists the candidate tips.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

N_ARM_JOINTS = 7
ROTARY = ("revolute", "continuous")
MOVABLE = ("revolute", "continuous", "prismatic", "floating", "planar")


class ChainError(ValueError):
    """The URDF's tree has no (or no unique) arm chain; the message says why in one line."""


@dataclass(frozen=True)
class Joint:
    """One URDF joint: its name, type, parent and child links and position limits (None if absent)."""

    name: str
    type: str
    parent: str
    child: str
    lower: float | None
    upper: float | None


@dataclass(frozen=True)
class Tree:
    """The URDF's links and joints (only what the chain selection needs)."""

    robot_name: str
    links: tuple[str, ...]
    joints: dict[str, Joint]  # by name
    parent_joint: dict[str, Joint]  # child link -> the joint above it
    children: dict[str, tuple[Joint, ...]]  # link -> the joints below it

    @property
    def root(self) -> str:
        """The one link without a parent joint."""
        roots = [link for link in self.links if link not in self.parent_joint]
        if len(roots) != 1:
            raise ChainError(f"the URDF has {len(roots)} root links ({', '.join(roots)}); it needs exactly one")
        return roots[0]

    def path(self, base: str, tip: str) -> list[Joint] | None:
        """Joints from `base` down to `tip`, in order; None when `tip` is not below `base`."""
        out: list[Joint] = []
        link = tip
        while link != base:
            joint = self.parent_joint.get(link)
            if joint is None:
                return None
            out.append(joint)
            link = joint.parent
        return out[::-1]


@dataclass(frozen=True)
class Chain:
    """The arm inside a URDF: its base and tip links, its 7 joints (base to tip), and every other
    movable joint with the position it is locked at."""

    base: str
    tip: str
    arm_joints: tuple[str, ...]
    locked: dict[str, float]  # joint name -> locked position (rad or m)


def read_tree(urdf_text: str, source: str = "URDF") -> Tree:
    """The link/joint tree of a URDF text; ChainError naming `source` when it is not a URDF."""
    try:
        root = ET.fromstring(urdf_text)
    except ET.ParseError as exc:
        raise ChainError(f"cannot parse {source}: {exc}") from None
    if root.tag != "robot":
        raise ChainError(f"{source} is not a URDF (its root element is <{root.tag}>, not <robot>)")
    links = tuple(el.get("name", "") for el in root.findall("link"))
    joints: dict[str, Joint] = {}
    for el in root.findall("joint"):
        parent, child, limit = el.find("parent"), el.find("child"), el.find("limit")
        if parent is None or child is None:
            raise ChainError(f"{source}: joint {el.get('name')!r} lacks a parent or child link")
        lower = upper = None
        if limit is not None and limit.get("lower") is not None and limit.get("upper") is not None:
            lower, upper = float(limit.get("lower", 0)), float(limit.get("upper", 0))
        name = el.get("name", "")
        joints[name] = Joint(name, el.get("type", "fixed"), parent.get("link", ""), child.get("link", ""), lower, upper)
    parent_joint = {j.child: j for j in joints.values()}
    children: dict[str, list[Joint]] = {link: [] for link in links}
    for j in joints.values():
        children.setdefault(j.parent, []).append(j)
    return Tree(root.get("name", ""), links, joints, parent_joint, {k: tuple(v) for k, v in children.items()})


def _extend_fixed(tree: Tree, link: str) -> str:
    """Follow fixed joints down from `link` while there is exactly one fixed child (flange, hand, TCP)."""
    while True:
        fixed = [j for j in tree.children.get(link, ()) if j.type == "fixed"]
        if len(fixed) != 1:
            return link
        link = fixed[0].child


def _continues(tree: Tree, link: str) -> bool:
    """True when a revolute joint hangs below `link` (directly or through fixed joints)."""
    for j in tree.children.get(link, ()):
        if j.type in ROTARY or (j.type == "fixed" and _continues(tree, j.child)):
            return True
    return False


def candidate_tips(tree: Tree, base: str) -> list[str]:
    """Tips of every chain from `base` whose 7 movable joints are all revolute and that no further
    revolute joint continues."""
    tips = []
    for joint in tree.joints.values():
        if joint.type not in ROTARY or _continues(tree, joint.child):
            continue
        path = tree.path(base, joint.child)
        if path is None:
            continue
        movable = [j for j in path if j.type in MOVABLE]
        if len(movable) == N_ARM_JOINTS and all(j.type in ROTARY for j in movable):
            tips.append(_extend_fixed(tree, joint.child))
    return tips


def locked_position(joint: Joint, given: Mapping[str, float]) -> float:
    """Where a locked joint sits: the sidecar's value, else its zero clipped into its limits."""
    if joint.name in given:
        return float(given[joint.name])
    value = 0.0
    if joint.lower is not None and joint.upper is not None and joint.lower <= joint.upper:
        value = min(max(value, joint.lower), joint.upper)
    return value


def select_chain(
    tree: Tree, base: str | None = None, tip: str | None = None, locked: Mapping[str, float] | None = None
) -> Chain:
    """The arm chain between `base` (default: the root) and `tip` (default: the only chain of 7
    revolute joints); every other movable joint is locked (`locked_position`). ChainError otherwise."""
    given = dict(locked or {})
    base = base or tree.root
    for role, link in (("base", base), ("tip", tip)):
        if link is not None and link not in tree.links:
            raise ChainError(f"no link {link!r} (--{role}) in the URDF; links are {', '.join(tree.links)}")
    if tip is None:
        tips = candidate_tips(tree, base)
        if not tips:
            raise ChainError(
                f"no 7-DOF arm (a chain of {N_ARM_JOINTS} revolute joints) starts at link {base!r};"
                " give --base and --tip"
                f" (links: {', '.join(tree.links)})"
            )
        if len(tips) > 1:
            raise ChainError(
                f"several {N_ARM_JOINTS}-joint chains start at {base!r}; choose one with --tip: {', '.join(tips)}"
            )
        tip = tips[0]
    path = tree.path(base, tip)
    if path is None:
        raise ChainError(f"link {tip!r} (--tip) is not below link {base!r} (--base)")
    movable = [j for j in path if j.type in MOVABLE]
    if len(movable) != N_ARM_JOINTS:
        raise ChainError(
            f"the chain from {base!r} to {tip!r} has {len(movable)} movable joints; torquelab needs a 7-DOF arm"
            f" (candidate tips from {base!r}: {', '.join(candidate_tips(tree, base)) or 'none'})"
        )
    for j in movable:
        if j.type not in ("revolute", "prismatic", "continuous"):
            raise ChainError(
                f"joint {j.name!r} of the chain is {j.type}; the arm's joints must be revolute or prismatic"
            )
    arm = tuple(j.name for j in movable)
    unknown = [name for name in given if name not in tree.joints]
    if unknown:
        raise ChainError(f"the sidecar locks joint {unknown[0]!r}, which the URDF lacks")
    in_arm = [name for name in given if name in arm]
    if in_arm:
        raise ChainError(f"the sidecar locks joint {in_arm[0]!r}, which is one of the arm's joints")
    locked_at = {
        j.name: locked_position(j, given) for j in tree.joints.values() if j.type in MOVABLE and j.name not in arm
    }
    for name, j in tree.joints.items():
        if name in locked_at and j.type in ("floating", "planar") and name in given:
            raise ChainError(f"joint {name!r} is {j.type}: it can only be locked at its zero")
    return Chain(base=base, tip=tip, arm_joints=arm, locked=locked_at)


def read_chain(
    urdf: Path, base: str | None = None, tip: str | None = None, locked: Mapping[str, float] | None = None
) -> tuple[Tree, Chain]:
    """`read_tree` and `select_chain` of a URDF file."""
    tree = read_tree(urdf.read_text(errors="replace"), urdf.name)
    return tree, select_chain(tree, base, tip, locked)
