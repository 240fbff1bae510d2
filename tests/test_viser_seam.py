"""What the app relies on of viser's private API (`app.live.ui.viser_seam`) holds on the installed viser.

Each test names one thing the seam reads or writes past viser's public handles and checks it on a
real server, so that an upgrade that renames or reshapes it fails here by name. The queued node
writes are held equal to viser's own setters in `tests/test_node_writes.py`.
"""

from __future__ import annotations

import asyncio
import sys
from importlib import metadata
from pathlib import Path

import numpy as np
import pytest
import viser
from packaging.requirements import Requirement
from packaging.version import Version

from app.live.ui.viser_seam import (
    VISER_RANGE,
    GuiUpdateMessage,
    gui_update_handlers,
    input_by_uuid,
    input_state,
    input_uuid,
    node_state,
    queue_orientation,
    queue_position,
)

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

ROOT = Path(__file__).resolve().parents[1]


def test_the_pinned_range_is_the_seams_and_the_installed_viser_is_inside_it():
    deps = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["dependencies"]
    (viser_dep,) = [Requirement(d) for d in deps if Requirement(d).name == "viser"]
    assert str(viser_dep.specifier) == str(Requirement("viser" + VISER_RANGE).specifier)
    installed = Version(metadata.version("viser"))
    assert viser_dep.specifier.contains(installed), f"viser {installed} is outside {VISER_RANGE}"


def _dispatch(server: viser.ViserServer, message: object, client_id: int = 7) -> None:
    """Hand a message to the server as its websocket does for a client's message."""
    asyncio.run(server.scene._websock_interface._handle_incoming_message(client_id, message))


def test_gui_update_handlers_are_the_list_the_server_runs_on_a_clients_update(server):
    slider = server.gui.add_slider("seam slider", min=0.0, max=10.0, step=0.5, initial_value=1.0)
    handlers = gui_update_handlers(server)
    assert len(handlers) >= 1 and all(callable(h) for h in handlers)  # viser's own (and a guard's)
    seen: list[tuple[int, str, dict]] = []
    inner = list(handlers)

    async def recorder(client_id, message):
        seen.append((client_id, message.uuid, dict(message.updates)))
        for h in inner:
            result = h(client_id, message)
            if asyncio.iscoroutine(result):
                await result

    handlers[:] = [recorder]
    try:
        _dispatch(server, GuiUpdateMessage(input_uuid(slider), {"value": 3.5}))
    finally:
        handlers[:] = inner
    assert seen == [(7, input_uuid(slider), {"value": 3.5})]  # the message's fields: uuid, updates
    assert slider.value == pytest.approx(3.5)  # and viser's handler, run from the list, applied it
    slider.remove()


def test_an_input_is_found_by_its_uuid_and_its_state_has_what_the_checks_read(server):
    slider = server.gui.add_slider("seam state", min=-1.0, max=1.0, step=0.1, initial_value=0.2)
    dropdown = server.gui.add_dropdown("seam choice", ("a", "b"), initial_value="b")
    button = server.gui.add_button("seam button")
    for handle in (slider, dropdown, button):
        uuid = input_uuid(handle)
        assert isinstance(uuid, str) and input_by_uuid(server, uuid) is handle
    state = input_state(slider)
    assert state.value == pytest.approx(0.2) and state.props.label == "seam state"
    assert (state.props.min, state.props.max) == (-1.0, 1.0) and state.is_button is False
    assert tuple(input_state(dropdown).props.options) == ("a", "b") and input_state(button).is_button is True
    calls: list[float] = []
    slider.on_update(lambda event: calls.append(event.target.value))
    assert len(state.update_cb) == 1  # the callbacks a test runs for a browser's update
    uuid = input_uuid(slider)
    for handle in (slider, dropdown, button):
        handle.remove()
    assert input_by_uuid(server, uuid) is None
    assert input_by_uuid(server, "no such input") is None


def test_a_nodes_state_is_its_pose_and_props_and_a_removed_node_says_so(server):
    label = server.scene.add_label("/seam_label", "x", position=(0.1, 0.2, 0.3))
    state = node_state(label, "position")
    assert isinstance(state.position, np.ndarray) and state.position.tolist() == pytest.approx([0.1, 0.2, 0.3])
    assert isinstance(state.wxyz, np.ndarray) and state.wxyz.shape == (4,)
    assert state.name == label.name and state.props.text == "x"
    queue_position(state, (1.0, 2.0, 3.0))
    queue_orientation(state, (0.0, 1.0, 0.0, 0.0))
    assert label.position.tolist() == [1.0, 2.0, 3.0] and label.wxyz.tolist() == [0.0, 1.0, 0.0, 0.0]
    label.remove()
    with pytest.raises(RuntimeError, match="'wxyz' on a removed"):
        node_state(label, "wxyz")
