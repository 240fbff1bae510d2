"""Per-frame writes to viser scene nodes at a fraction of the setters' cost.

The publisher moves some forty nodes thirty times a second. viser's own setters are built for
occasional writes: each `handle.position = …` casts the value, runs `np.allclose` against the stored
pose, and each generic property write (`points`, `scale`, `color`, `text`) evaluates four
`npt.NDArray[…]` type aliases before it compares. On a 2-core machine shared with the browser that
was close to half of the publisher's CPU time. The functions here queue the very same messages and
keep the handle's state the same as the setters do (tests/test_node_writes.py checks both against
the setters), with plain float comparisons instead; what they need of viser's private API comes
from `app.live.ui.viser_seam`.

The write is skipped when the new value equals the stored one exactly; viser's setters skip within
`np.allclose` tolerances. A pose that moves by less than that tolerance is therefore sent here and
not there: it only matters for a node at rest, whose value then equals its stored one.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import viser

from app.live.ui.viser_seam import node_state, queue_orientation, queue_position, queue_prop_update


def set_position(handle: viser.SceneNodeHandle, xyz: Sequence[float] | np.ndarray) -> None:
    """`handle.position = xyz` (world or parent frame, metres); no message when unchanged."""
    if len(xyz) != 3:
        raise ValueError(f"Expected a position of length 3, got {len(xyz)}")
    value = (float(xyz[0]), float(xyz[1]), float(xyz[2]))
    state = node_state(handle, "position")
    if tuple(state.position.tolist()) == value:
        return
    queue_position(state, value)


def set_wxyz(handle: viser.SceneNodeHandle, wxyz: Sequence[float] | np.ndarray) -> None:
    """`handle.wxyz = wxyz` (unit quaternion, scalar first); no message when unchanged."""
    if len(wxyz) != 4:
        raise ValueError(f"Expected a quaternion of length 4, got {len(wxyz)}")
    value = (float(wxyz[0]), float(wxyz[1]), float(wxyz[2]), float(wxyz[3]))
    state = node_state(handle, "wxyz")
    if tuple(state.wxyz.tolist()) == value:
        return
    queue_orientation(state, value)


def set_pose(
    handle: viser.SceneNodeHandle, xyz: Sequence[float] | np.ndarray, wxyz: Sequence[float] | np.ndarray
) -> None:
    """Position and orientation of one node (see `set_position`, `set_wxyz`)."""
    set_position(handle, xyz)
    set_wxyz(handle, wxyz)


def set_prop(handle: viser.SceneNodeHandle, name: str, value: Any) -> None:
    """`setattr(handle, name, value)` for a node property (`points`, `scale`, `color`, `text`, …).

    An array property takes an array of its stored dtype (e.g. float32 `points`); anything else
    (a float64 array, a list) goes through viser's own setter, which casts it. No message when
    the value equals the stored one.
    """
    if isinstance(getattr(type(handle), name, None), property):  # a setter of its own: let it run
        setattr(handle, name, value)
        return
    state = node_state(handle, name)
    current = getattr(state.props, name)
    if isinstance(current, np.ndarray):
        if not isinstance(value, np.ndarray) or value.dtype != current.dtype:
            setattr(handle, name, value)
            return
        if value.shape == current.shape:
            if np.array_equal(current, value):
                return
            current[:] = value
        else:
            setattr(state.props, name, value.copy())
        queued: Any = value.copy()  # neither the caller's array nor the stored one goes on the wire
    else:
        if isinstance(value, np.ndarray):
            setattr(handle, name, value)
            return
        if current == value:
            return
        setattr(state.props, name, value)
        queued = value
    queue_prop_update(handle, name, queued)
