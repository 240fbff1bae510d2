"""The 3D scene: one draggable mesh per robot link, a floor, the table, and the overlays.

Every link is a frame `/robot/<link>` (moved each visual frame to the simulated body pose) with
a mesh child built from the URDF's visuals (primitives and mesh files, `robots.meshes`, cached) in
the link's own frame, in the link's own colour when limit colours do not apply. Each mesh has an
`on_drag` binding: a left-drag on any link becomes `DragCommand`s (grab → move… → release) for
the simulation loop, which applies the spring every step (DESIGN §4, §6). The callbacks are
`async` so viser runs them in order on its event loop; they only hand a command to `drag_sink`.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import trimesh
import viser

import robots.meshes
from app.core.commands import DragCommand
from app.live.ui.node_writes import set_pose, set_position, set_prop
from app.live.ui.overlay_shapes import margin_color
from app.live.ui.overlays import Overlays
from app.live.ui.snapshot import SceneSnapshot
from app.live.ui.visuals import VisualSettings
from robots import RobotDescription

TWIN_COLOR = (255, 159, 28)  # the twin arm (app.core.twin), translucent
TWIN_OPACITY = 0.35
NEUTRAL = (175, 178, 186)  # links without a joint of their own (base) or with limit colours off
FLOOR_COLOR = (200, 200, 205)
TABLE_COLOR = (160, 125, 90)
# Where a new browser's camera starts (and "Reset View" returns): front-right of the arm.
CAMERA_POSITION = (1.55, -1.35, 1.05)
CAMERA_LOOK_AT = (0.25, 0.0, 0.4)


def link_meshes(urdf_path: str, package_paths: tuple = ()) -> dict[str, trimesh.Trimesh]:
    """One mesh per URDF link from its visuals (cylinders, spheres, boxes, mesh files), in the link
    frame, its colour in metadata["color"]: `robots.meshes.link_meshes` (read once, cached)."""
    return robots.meshes.link_meshes(urdf_path, tuple(package_paths))


def add_ghost_arm(
    server: viser.ViserServer,
    root: str,
    shapes: dict[str, trimesh.Trimesh],
    color: tuple[int, int, int],
    opacity: float,
    visible: bool = True,
) -> dict[str, viser.MeshHandle]:
    """Translucent, non-draggable copies of the link shapes under `root` (twin arm, self-motion ghost)."""
    return {
        name: server.scene.add_mesh_simple(
            f"{root}/{name}",
            mesh.vertices,
            mesh.faces,
            color=color,
            opacity=opacity,
            cast_shadow=False,
            receive_shadow=False,
            visible=visible,
        )
        for name, mesh in shapes.items()
    }


def pose_ghost_arm(
    meshes: dict[str, viser.MeshHandle], names: tuple[str, ...] | list[str], positions: np.ndarray, wxyz: np.ndarray
) -> None:
    """Put each ghost link at its pose (rows of `positions`, `wxyz` in the order of `names`) and show it."""
    for i, name in enumerate(names):
        handle = meshes.get(name)
        if handle is None:
            continue
        set_pose(handle, positions[i], wxyz[i])
        if not handle.visible:
            handle.visible = True


def hide_ghost_arm(meshes: dict[str, viser.MeshHandle]) -> None:
    """Hide every link of a ghost arm."""
    for handle in meshes.values():
        if handle.visible:
            handle.visible = False


def link_joint_indices(robot: RobotDescription) -> dict[str, int]:
    """Link name → index (0..6) of the joint that moves it; -1 for links fixed to the base."""
    out = {}
    for frame in robot.model.frames:
        if frame.name in robot.link_names:
            out[frame.name] = int(frame.parentJoint) - 1
    return out


class SceneView:
    """The robot and its overlays in one viser scene; `update` sets light properties only."""

    def __init__(
        self,
        server: viser.ViserServer,
        robot: RobotDescription,
        drag_sink: Callable[[DragCommand], None],
        settings: VisualSettings | None = None,
        root: str = "/robot",
    ):
        self.server = server
        self.robot = robot
        self.drag_sink = drag_sink
        self.settings = settings or VisualSettings()
        self.root = root
        self.joint_of = link_joint_indices(robot)
        meshes = link_meshes(str(robot.urdf_path), robot.package_paths)
        self._link_shapes = meshes
        # mesh files not found or not readable: their links are drawn as nothing (the publisher says so once)
        self.missing_meshes = robots.meshes.mesh_problems(robot.urdf_path, tuple(robot.package_paths))
        self.frames: dict[str, viser.FrameHandle] = {}
        self.meshes: dict[str, viser.MeshHandle] = {}
        for name in robot.link_names:
            frame = server.scene.add_frame(f"{root}/{name}", show_axes=False)
            self.frames[name] = frame
            if name not in meshes:
                continue
            mesh = meshes[name]
            handle = server.scene.add_mesh_simple(
                f"{root}/{name}/mesh", mesh.vertices, mesh.faces, color=self._base_color(name), flat_shading=False
            )
            handle.on_drag("left")(self._drag_callback(name))
            self.meshes[name] = handle
        self.floor = server.scene.add_grid(
            "/floor", width=3.0, height=3.0, cell_size=0.1, section_size=0.5, plane="xy", position=(0.0, 0.0, 0.0)
        )
        self.table: viser.BoxHandle | None = None
        self._table_key: tuple[float, ...] | None = None
        self.overlays = Overlays(server, self.settings)
        server.initial_camera.position = CAMERA_POSITION
        server.initial_camera.look_at = CAMERA_LOOK_AT
        server.initial_camera.up = (0.0, 0.0, 1.0)
        self._colors: dict[str, tuple[int, int, int]] = {}
        self.twin_meshes: dict[str, viser.MeshHandle] = {}
        self.twin_label: viser.LabelHandle | None = None

    def _base_color(self, link: str) -> tuple[int, int, int]:
        """A link's own colour (URDF material or mesh file), NEUTRAL without one."""
        shape = self._link_shapes.get(link)
        color = None if shape is None else shape.metadata.get("color")
        return NEUTRAL if color is None else (int(color[0]), int(color[1]), int(color[2]))

    # ---- interaction --------------------------------------------------------------------------
    def _drag_callback(self, link: str):
        sink = self.drag_sink

        async def on_drag(event: viser.SceneNodeDragEvent) -> None:
            if event.phase == "start":
                sink(DragCommand("grab", event.client_id, body_name=link, point_world=_vec(event.start_position)))
            elif event.phase == "update":
                sink(DragCommand("move", event.client_id, body_name=link, target_world=_vec(event.end_position)))
            else:
                sink(DragCommand("release", event.client_id, body_name=link))

        return on_drag

    # ---- per visual frame ---------------------------------------------------------------------
    def update(self, snap: SceneSnapshot) -> None:
        """Move the links to the snapshot's poses, recolour by joint-limit margin, update overlays."""
        for i, name in enumerate(snap.link_names):
            frame = self.frames.get(name)
            if frame is None:
                continue
            position, wxyz = snap.link_positions[i], snap.link_wxyz[i]
            if np.isfinite(position).all() and np.isfinite(wxyz).all():
                set_pose(frame, position, wxyz)
        self._update_colors(snap)
        self._update_table(snap)
        self._update_twin(snap)
        self.overlays.update(snap)

    def _update_twin(self, snap: SceneSnapshot) -> None:
        """The twin arm: translucent, not draggable, labelled with its objective; hidden without one."""
        positions, wxyz = snap.twin_link_positions, snap.twin_link_wxyz
        show = positions is not None and wxyz is not None and bool(np.all(np.isfinite(positions)))
        if not show:
            hide_ghost_arm(self.twin_meshes)
            if self.twin_label is not None and self.twin_label.visible:
                self.twin_label.visible = False
            return
        assert positions is not None and wxyz is not None
        if not self.twin_meshes:
            self.twin_meshes = add_ghost_arm(self.server, "/twin", self._link_shapes, TWIN_COLOR, TWIN_OPACITY)
            self.twin_label = self.server.scene.add_label("/twin_label", "twin")
        pose_ghost_arm(self.twin_meshes, snap.link_names, positions, wxyz)
        if self.twin_label is not None:
            middle = len(snap.link_names) // 2
            set_position(self.twin_label, positions[middle] + np.array([0.0, 0.0, 0.08]))
            W = snap.twin_W.get("W")
            text = f"twin: W_{snap.twin_objective}" + (f" = {W:.3g}" if W is not None else "")
            set_prop(self.twin_label, "text", text)
            if not self.twin_label.visible:
                self.twin_label.visible = True

    def _update_colors(self, snap: SceneSnapshot) -> None:
        s = self.settings
        for name, mesh in self.meshes.items():
            j = self.joint_of.get(name, -1)
            if not s.limit_colors or j < 0:
                color = self._base_color(name)
            else:
                zone = s.limit_zone_rad if snap.limit_zone is None else float(snap.limit_zone[j])
                color = margin_color(float(snap.joint_margins[j]), zone)
            if self._colors.get(name) != color:
                mesh.color = color
                self._colors[name] = color

    def _update_table(self, snap: SceneSnapshot) -> None:
        key = None if snap.table is None else tuple(np.round(np.concatenate(snap.table), 4))
        if key == self._table_key:
            return
        self._table_key = key
        if self.table is not None:
            self.table.remove()
            self.table = None
        if snap.table is not None:
            center, half = snap.table
            self.table = self.server.scene.add_box(
                "/table", color=TABLE_COLOR, dimensions=tuple(2 * half), position=tuple(center)
            )

    def remove(self) -> None:
        """Remove every node this view added (on robot switch or shutdown)."""
        self.overlays.remove()
        for handle in self.meshes.values():
            handle.remove()
        for frame in self.frames.values():
            frame.remove()
        self.floor.remove()
        if self.table is not None:
            self.table.remove()
        for handle in self.twin_meshes.values():
            handle.remove()
        if self.twin_label is not None:
            self.twin_label.remove()
        self.meshes.clear()
        self.frames.clear()
        self.twin_meshes.clear()


def _vec(p) -> tuple[float, float, float]:
    return (float(p[0]), float(p[1]), float(p[2]))
