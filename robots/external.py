"""Arms loaded by name from an optional package instead of files in this repository.

The Franka Panda comes from `example-robot-data` (PyPI, BSD-3; the Pinocchio ecosystem's robot
descriptions, installed with `pip install 'torquelab[robots]'`): its wheel puts the URDF and the
meshes under `cmeel.prefix/share/example-robot-data/robots/`. The sidecar with what the URDF lacks
is shipped here (robots/panda.toml).
"""

from __future__ import annotations

import importlib.metadata
from pathlib import Path

DISTRIBUTION = "example-robot-data"
INSTALL_HINT = "pip install 'torquelab[robots]' (or: pip install example-robot-data)"
SHARE = "cmeel.prefix/share/example-robot-data/robots"
URDFS = {"panda": "panda_description/urdf/panda.urdf"}


class NotInstalled(LookupError):
    """The package that holds a robot's description is not installed; the message says how to."""


def urdf_path(name: str) -> Path:
    """The URDF of the external robot `name`; NotInstalled with the install command otherwise."""
    try:
        dist = importlib.metadata.distribution(DISTRIBUTION)
    except importlib.metadata.PackageNotFoundError:
        raise NotInstalled(f"robot {name!r} needs the {DISTRIBUTION} package: {INSTALL_HINT}") from None
    path = Path(str(dist.locate_file(f"{SHARE}/{URDFS[name]}")))
    if not path.is_file():
        raise NotInstalled(f"{DISTRIBUTION} is installed but lacks {URDFS[name]}; reinstall it: {INSTALL_HINT}")
    return path


def installed(name: str) -> bool:
    """True when `urdf_path(name)` finds the file."""
    try:
        urdf_path(name)
    except NotInstalled:
        return False
    return True
