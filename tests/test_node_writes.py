"""The publisher's fast node writes queue what viser's own setters queue, and leave the same state."""

from __future__ import annotations

from contextlib import contextmanager

import numpy as np
import pytest

from app.live.ui.node_writes import set_pose, set_position, set_prop, set_wxyz
from app.live.ui.viser_seam import node_state


@contextmanager
def recorded(server):
    """Messages the scene queues inside the block."""
    interface = server.scene._websock_interface
    messages: list = []
    original = interface.queue_message

    def record(message):
        messages.append(message)
        original(message)

    interface.queue_message = record
    try:
        yield messages
    finally:
        del interface.queue_message


def _fields(message, name: str) -> dict:
    out = {}
    for key, value in vars(message).items():
        if isinstance(value, str):
            value = value.replace(name, "<node>")
        elif isinstance(value, dict):
            value = {k: _plain(v) for k, v in value.items()}
        out[key] = value
    return out


def _same_messages(via_setter: list, via_fast: list, name_a: str, name_b: str) -> None:
    assert [type(m).__name__ for m in via_fast] == [type(m).__name__ for m in via_setter]
    for a, b in zip(via_setter, via_fast, strict=True):
        assert _fields(b, name_b) == _fields(a, name_a)


def _plain(value):
    return (value.tolist(), str(value.dtype)) if isinstance(value, np.ndarray) else value


def _state(handle) -> dict:
    props = {k: _plain(v) for k, v in vars(node_state(handle, "props").props).items()}
    return {"position": handle.position.tolist(), "wxyz": handle.wxyz.tolist(), "props": props}


def _writes(rng):
    """A sequence of (kind, value) writes: changes, repeats (no message) and shape changes."""
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    points = rng.normal(size=(4, 2, 3)).astype(np.float32)
    return [
        ("position", rng.normal(size=3)),
        ("position", None),  # the same again: nothing queued
        ("wxyz", q),
        ("wxyz", None),
        ("points", points),
        ("points", points.copy()),  # equal: nothing queued
        ("points", (points + 1.0).astype(np.float32)),  # same shape, new values
        ("points", rng.normal(size=(6, 2, 3)).astype(np.float32)),  # new shape
        ("points", rng.normal(size=(6, 2, 3))),  # float64: viser's own cast
        ("thickness", 3.5),
    ]


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_fast_writes_queue_the_setters_messages_and_state(server, seed):
    rng = np.random.default_rng(seed)
    start = np.zeros((1, 2, 3), dtype=np.float32)
    a = server.scene.add_line_segments(f"/writes_a{seed}", start, colors=(0, 0, 0))
    b = server.scene.add_line_segments(f"/writes_b{seed}", start, colors=(0, 0, 0))
    last: dict = {}
    for kind, value in _writes(rng):
        value = last[kind] if value is None else value
        last[kind] = value
        with recorded(server) as via_setter:
            setattr(a, kind, value)
        with recorded(server) as via_fast:
            if kind == "position":
                set_position(b, value)
            elif kind == "wxyz":
                set_wxyz(b, value)
            else:
                set_prop(b, kind, value)
        _same_messages(via_setter, via_fast, a.name, b.name)
        assert _state(b) == _state(a), kind
    a.remove()
    b.remove()


def test_fast_writes_cover_labels_meshes_and_frames(server):
    rng = np.random.default_rng(3)
    pairs = [
        (server.scene.add_label("/wl_a", "x"), server.scene.add_label("/wl_b", "x")),
        (server.scene.add_frame("/wf_a", show_axes=False), server.scene.add_frame("/wf_b", show_axes=False)),
        (server.scene.add_icosphere("/wi_a", 0.1), server.scene.add_icosphere("/wi_b", 0.1)),
    ]
    for a, b in pairs:
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        p = rng.normal(size=3)
        with recorded(server) as via_setter:
            a.position = tuple(p)
            a.wxyz = tuple(q)
        with recorded(server) as via_fast:
            set_pose(b, p, q)
        _same_messages(via_setter, via_fast, a.name, b.name)
        extra = {"text": "W_a = 0.5"} if hasattr(node_state(a, "props").props, "text") else {}
        if hasattr(node_state(a, "props").props, "color"):
            extra["color"] = (200, 10, 10)
        if hasattr(node_state(a, "props").props, "scale"):
            extra["scale"] = (0.1, 0.2, 0.3)
        for kind, value in extra.items():
            for _ in range(2):  # the second is a repeat: nothing queued
                with recorded(server) as via_setter:
                    setattr(a, kind, value)
                with recorded(server) as via_fast:
                    set_prop(b, kind, value)
                _same_messages(via_setter, via_fast, a.name, b.name)
        assert _state(b) == _state(a)
        a.remove()
        b.remove()


def test_fast_writes_refuse_a_removed_node_and_a_wrong_length(server):
    handle = server.scene.add_frame("/w_removed", show_axes=False)
    with pytest.raises(ValueError, match="length 3"):
        set_position(handle, (1.0, 2.0))
    with pytest.raises(ValueError, match="length 4"):
        set_wxyz(handle, (1.0, 0.0, 0.0))
    handle.remove()
    with pytest.raises(RuntimeError, match="removed"):
        set_position(handle, (0.0, 0.0, 1.0))
    with pytest.raises(RuntimeError, match="removed"):
        set_prop(handle, "show_axes", True)
