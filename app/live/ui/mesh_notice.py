"""The "Missing meshes" notice: once per robot to the pages open when its scene is built, and once to
each page that opens later while that robot is shown (through the loop's notices, like any other)."""

from __future__ import annotations

from typing import Any

from robots.meshes import missing_meshes_text

TITLE = "Missing meshes"


class MeshNotice:
    """Says which mesh files the shown robot draws as nothing; run by the publisher thread only."""

    def __init__(self, server: Any, loop: Any):
        self.server = server
        self.loop = loop
        self.robot: tuple[str, tuple[str, ...]] | None = None  # the robot it was said for (URDF, packages)
        self.body = ""  # the notice for that robot ("" when every mesh was read)
        self.told: set[int] = set()  # pages that got it (client ids)
        self._broadcast = False  # a notice to every page queued and not yet sent

    def robot_shown(self, robot: Any, problems: dict[str, str]) -> None:
        """A scene for `robot` was built (`problems`: its files drawn as nothing): one notice to every
        page, unless the robot is the one shown before (a preset switch says nothing again)."""
        key = (str(getattr(robot, "urdf_path", "")), tuple(str(p) for p in getattr(robot, "package_paths", ())))
        if key == self.robot:
            return
        self.robot, self.told = key, set()
        text = missing_meshes_text(problems)
        self.body = f"{robot.name}: {text}" if text else ""
        if self.body:
            self.loop.notify("warning", TITLE, self.body)
            self._broadcast = True

    def notices_sent(self) -> None:
        """After the loop's notices went out: the pages open then have it; each page open now that
        has not gets it (queued for the next sending)."""
        if not self.body:
            return
        clients = set(self.server.get_clients())
        if self._broadcast:
            self.told, self._broadcast = set(clients), False
        self.told &= clients  # closed pages forgotten
        for client_id in sorted(clients - self.told):
            self.told.add(client_id)
            self.loop.notify("warning", TITLE, self.body, client_id=client_id)
