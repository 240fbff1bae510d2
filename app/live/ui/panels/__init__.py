"""GUI panels, one per file: Scenario, Motion–force, Nullspace, Compliance, Safety, Latency, Record/Export.

Every panel only reads the loop's published frames and writes commands; none touches the session.
A parameter panel is a list of "group.field" names (`app.live.ui.panels.base`); `ALL_FIELDS` lists
every name some panel shows, so the More gains fold shows the rest.
"""

from __future__ import annotations

from app.live.ui.panels.compliance import FIELDS as COMPLIANCE_FIELDS
from app.live.ui.panels.compliance import JOINT_FIELDS
from app.live.ui.panels.latency import FIELDS as LATENCY_FIELDS
from app.live.ui.panels.motion_force import FIELDS as MOTION_FORCE_FIELDS
from app.live.ui.panels.nullspace import FIELDS as NULLSPACE_FIELDS
from app.live.ui.panels.safety import FIELDS as SAFETY_FIELDS
from app.live.ui.panels.scenario import FIELDS as SCENARIO_FIELDS

ALL_FIELDS: tuple[str, ...] = (
    *SCENARIO_FIELDS,
    *MOTION_FORCE_FIELDS,
    *NULLSPACE_FIELDS,
    *COMPLIANCE_FIELDS,
    *JOINT_FIELDS,
    *SAFETY_FIELDS,
    *LATENCY_FIELDS,
)
