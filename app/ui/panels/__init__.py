"""GUI panels, one per file: Scenario, Motion–force, Nullspace, Compliance, Safety, Record/Export.

Every panel only reads the loop's published frames and writes commands; none touches the session.
`ALL_KNOBS` lists every bound knob so the loop can read their current values.
"""

from __future__ import annotations

from app.ui.panels.base import Knob
from app.ui.panels.compliance import KNOBS as COMPLIANCE_KNOBS
from app.ui.panels.motion_force import KNOBS as MOTION_FORCE_KNOBS
from app.ui.panels.nullspace import KNOBS as NULLSPACE_KNOBS
from app.ui.panels.safety import KNOBS as SAFETY_KNOBS

ALL_KNOBS: tuple[Knob, ...] = (*MOTION_FORCE_KNOBS, *NULLSPACE_KNOBS, *COMPLIANCE_KNOBS, *SAFETY_KNOBS)
