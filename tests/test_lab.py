"""The lab without threads: commands, single steps in chunks, halts, and Reset that always recovers."""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np
import pytest

from app.core.commands import DragCommand, Pause, Play, Reset, SetParam, SetSpeed, SettleNow, StepOnce, SwitchSession
from app.core.recovery import RECOVERY_STEPS
from app.live.lab import Lab
from app.live.overpowered import OVERPOWERED_CHECK_STEPS
from app.live.run_flags import RunFlags
from app.scenarios import Environment, Scenario
from app.scenarios.free import FreeScenario
from control.params import ParamGroup, expect, param


@dataclass(frozen=True)
class FuseParams(ParamGroup):
    gain: float = param(1.0, label="gain", lo=0.0, hi=10.0, step=0.1)
    blow_at_s: float = param(1e9, label="blow at", unit="s", lo=0.0, hi=1e9)
    how: str = param("raise", label="how", choices=("raise", "nan"))


class Fuse(Environment):
    """An environment with a harmless `gain`, and `blow_at_s`, after which every step raises (as a
    gain of the wrong type did) or pushes NaN into the state — valid values that halt."""

    def __init__(self) -> None:
        self.set_params("fuse", FuseParams())

    def params(self) -> dict[str, ParamGroup]:
        return {"fuse": FuseParams(self.gain, self.blow_at_s, self.how)}

    def set_params(self, name: str, group) -> None:
        p = expect(name, group, FuseParams if name == "fuse" else None)
        self.gain, self.blow_at_s, self.how = p.gain, p.blow_at_s, p.how

    def apply(self, world, t: float) -> dict[str, float]:
        if t >= self.blow_at_s:
            if self.how == "raise":
                raise TypeError("unsupported operand type(s) for *: 'float' and 'str'")
            world.data.qvel[0] = np.nan
        return {"gain": self.gain}


class FuseScenario(FreeScenario):
    name = "fuse"

    def make_environment(self, world, rng) -> Environment:
        return Fuse()


def _lab(scenario: Scenario | str = "free") -> Lab:
    return Lab(FuseScenario() if scenario == "fuse" else scenario)


def _recovered(lab: Lab) -> bool:
    """Not halted, and RECOVERY_STEPS steps run without a halt."""
    return not lab.halted and not lab.advance(RECOVERY_STEPS).halted and not lab.halted


def test_a_single_step_runs_in_chunks_and_pause_cancels_the_rest():
    lab = _lab()
    run = RunFlags(lab)
    run.apply(StepOnce(1200))
    assert run.pending_steps == 1200 and lab.session.steps == 0
    run.step_pending(500)
    assert lab.session.steps == 500 and run.pending_steps == 700
    run.apply(Pause())
    assert run.pending_steps == 0 and run.step_pending(500) is None and lab.session.steps == 500
    for bad in (0, -3, 10_001, 2.5, "7", None, float("nan")):
        n = len(lab.notice_log)
        run.apply(StepOnce(bad))  # type: ignore[arg-type]
        assert len(lab.notice_log) == n + 1 and run.pending_steps == 0


def test_settle_now_runs_the_settle_phase_in_chunks_then_goes_on_paced_and_pause_or_reset_stop_it():
    """Polish with W_j (it converges about a second after contact): "Settle now" runs chunks until
    the trajectory starts, within one chunk of it, then the lab runs on paced (a pacing restart);
    with nothing left to settle, or in a preset without a settle phase, it is refused."""
    chunk = 100
    lab = Lab("polish", robot="rizon4s", executor="projection")
    run = RunFlags(lab)
    run.apply(SetParam("nullspace", "objective", "j"))
    run.apply(SettleNow())
    assert run.settling and run.running
    epoch = run.pacing_epoch
    chunks = 0
    while run.settling and chunks < 200:  # 20 s simulated at most
        run.settle_chunk(chunk)
        chunks += 1
    assert not run.settling and run.running and not lab.session.settle_pending()
    assert run.pacing_epoch == epoch + 1
    start = lab.session.environment.clock.trajectory_start
    assert start is not None and 1.0 < start and 0.0 <= lab.session.world.time - start < chunk * lab.dt + 1e-9
    assert lab.notice_log[-1].title == "Settled"
    assert run.settle_chunk(chunk) is None  # over: the loop steps paced again
    n = len(lab.notice_log)
    run.apply(SettleNow())
    assert not run.settling and len(lab.notice_log) == n + 1 and lab.notice_log[-1].title == "Refused"

    run.apply(Reset())
    assert lab.session.settle_pending()
    run.apply(SettleNow())
    run.settle_chunk(chunk)
    run.apply(Pause())
    t = lab.session.world.time
    assert not run.settling and not run.running and run.settle_chunk(chunk) is None and lab.session.world.time == t
    run.apply(SettleNow())
    run.settle_chunk(chunk)
    run.apply(Reset())
    assert not run.settling and lab.session.world.time == 0.0

    free = RunFlags(_lab())
    free.apply(SettleNow())
    assert not free.settling and free.lab.notice_log[-1].title == "Refused"


def test_a_halt_pauses_with_its_reason_and_reset_resumes_what_ran():
    lab = _lab("fuse")
    run = RunFlags(lab)
    run.apply(Play())
    run.apply(SetParam("fuse", "blow_at_s", 0.05))
    run.apply(SetParam("fuse", "how", "nan"))
    run.advance(200)
    assert "diverged" in lab.halted and not run.running
    run.apply(Play())  # refused while halted
    run.apply(StepOnce(5))
    assert not run.running and run.pending_steps == 0
    run.apply(Reset())
    assert run.running and _recovered(lab)
    assert any(n.title == "Setting dropped" and "blow_at_s" in n.body for n in lab.notice_log)


def test_reset_drops_the_overrides_since_the_last_healthy_run_newest_first_and_keeps_older_ones():
    lab = _lab("fuse")
    lab.apply(SetParam("fuse", "gain", 2.0))
    lab.advance(RECOVERY_STEPS)  # the gain ran healthy
    lab.apply(SetParam("fuse", "blow_at_s", 0.0))
    lab.apply(SetParam("fuse", "how", "raise"))  # harmless on its own, but newer
    lab.apply(SetParam("drag", "max_force_n", 77.0))
    result = lab.advance(50)
    assert result.stop == "error" and isinstance(result.error, TypeError) and "TypeError" in lab.halted
    n0 = len(lab.notice_log)
    lab.apply(Reset())
    dropped = [n.body for n in list(lab.notice_log)[n0:] if n.title == "Setting dropped"]
    # newest first, stopping as soon as the preset runs again: the drag limit and `how` go, then blow_at_s
    assert [d.split(" (")[0] for d in dropped] == [
        "drag.max_force_n = 77.0",
        "fuse.how = 'raise'",
        "fuse.blow_at_s = 0.0",
    ]
    assert all("since the simulation last ran healthy" in d for d in dropped)
    assert [(o.group, o.field, o.value) for o in lab.overrides] == [("fuse", "gain", 2.0)]
    assert lab.session.environment.gain == 2.0 and lab.session.steps == 0  # back at t = 0, gain kept
    assert _recovered(lab)


def test_reset_without_a_halt_keeps_every_override():
    lab = _lab("fuse")
    lab.apply(SetParam("fuse", "blow_at_s", 0.5))
    lab.apply(SetParam("drag", "max_force_n", 42.0))
    lab.advance(100)
    lab.apply(Reset())
    assert len(lab.overrides) == 2 and lab.session.environment.blow_at_s == 0.5 and lab.session.drag.max_force_n == 42


def test_the_drag_belongs_to_the_client_that_grabbed_it_and_a_reset_releases_it():
    lab = _lab()
    s = lab.session
    body = s.world.model.body(s.world.wrist_body).name
    p0 = tuple(s.world.site_pose(s.world.tcp_site)[0])
    lab.apply(DragCommand("grab", client_id=4, body_name=body, point_world=p0))
    lab.apply(DragCommand("move", client_id=2, target_world=(0.0, 0.0, 0.0)))  # not the holder: ignored
    lab.apply(DragCommand("release", client_id=2))
    assert s.drag.active and lab.drag_client == 4
    np.testing.assert_allclose(s.drag.target_world, p0)
    lab.apply(DragCommand("move", client_id=4, target_world=(0.3, 0.2, 0.3)))
    lab.advance(20)
    assert s.drag.state is not None and np.linalg.norm(s.drag.state.force_world) > 1.0
    lab.apply(DragCommand("release", client_id=4))
    assert not s.drag.active and lab.drag_client is None
    lab.apply(DragCommand("grab", client_id=3, body_name=body, point_world=p0))
    lab.apply(Reset())
    assert not lab.session.drag.active and lab.drag_client is None


def test_the_torque_delay_is_a_world_setting_that_survives_a_reset_and_a_refused_one_changes_nothing():
    lab = _lab()
    lab.apply(SetParam("world", "torque_delay_ms", 5.0, client_id=7))
    lab.apply(Reset())
    assert lab.session.world.torque_delay_steps == 5
    assert lab.settings.values["world"]["torque_delay_ms"] == pytest.approx(5.0)
    n0 = len(lab.notice_log)
    lab.apply(SetParam("world", "torque_delay_ms", 1e9, client_id=7))
    assert len(lab.notice_log) == n0 + 1 and lab.session.world.torque_delay_steps == 5


def test_an_executor_switch_keeps_the_simulation_state():
    lab = _lab()
    lab.advance(10)
    t, q = lab.session.world.time, lab.session.world.q.copy()
    lab.apply(SwitchSession(executor="joint-hold"))
    assert lab.session.executor_name == "joint-hold" and lab.session.world.time == t
    np.testing.assert_array_equal(lab.session.world.q, q)


def test_the_speed_is_limited_to_a_hundredth_to_unpaced():
    from app.live.run_flags import SPEED_RANGE

    run = RunFlags(_lab())
    run.apply(SetSpeed(0.25))
    assert run.speed == 0.25
    for bad in (0.005, SPEED_RANGE[1] * 2, float("nan"), "fast"):
        run.apply(SetSpeed(bad))  # type: ignore[arg-type]
        assert run.speed == 0.25 and run.lab.notice_log[-1].title == "Refused"
    run.apply(SetSpeed(0.01))
    assert run.speed == 0.01


JUNK = (
    -1.0,
    0.0,
    1e6,
    1e300,
    -1e300,
    float("nan"),
    float("inf"),
    "5",
    "abc",
    None,
    [1, 2],
    [[1.0], [2.0]],
    [0.0] * 7,
    True,
)


def _random_change(lab: Lab, rng: np.random.Generator) -> SetParam:
    """A change of a setting the lab shows, to an in-range-ish multiple of its value or to junk."""
    values = lab.settings.values
    targets = [t for t in values if values[t]]
    target = targets[rng.integers(len(targets))]
    keys = sorted(values[target])
    key = keys[rng.integers(len(keys))]
    now = values[target][key]
    if rng.random() < 0.5 and isinstance(now, (int, float)) and not isinstance(now, bool):
        value: object = float(now) * float(rng.choice([0.0, 0.5, 2.0, 10.0, 100.0]))
    else:
        value = JUNK[rng.integers(len(JUNK))]
    return SetParam(target, key, value)


@pytest.mark.parametrize("scenario", ["free", "polish", "compliance", "limit-drop", "mass-drop", "fuse"])
def test_seeded_fuzz_after_every_halt_reset_recovers(scenario):
    """Random changes (in range, out of range, junk) interleaved with steps: nothing escapes, and
    after every halt one Reset leads to RECOVERY_STEPS healthy steps (zero stuck states)."""
    rng = np.random.default_rng(10)
    lab = _lab(scenario)
    halts = 0
    for k in range(60):
        if scenario == "fuse" and k % 5 == 3:
            lab.apply(SetParam("fuse", "blow_at_s", lab.session.world.time + 0.01))
        else:
            lab.apply(_random_change(lab, rng))
        if not lab.halted:
            lab.advance(int(rng.integers(1, 40)))
        if lab.halted:
            halts += 1
            lab.apply(Reset())
            assert _recovered(lab), f"stuck after change {k}: {lab.halted}"
    print(f"{scenario}: {halts} halts, each recovered by one Reset")
    if scenario == "fuse":
        assert halts >= 5  # the property was exercised


def test_a_new_preset_starts_from_its_defaults_but_keeps_the_drag_settings():
    lab = _lab()
    lab.apply(SetParam("drag", "max_force_n", 55.0))
    lab.apply(SetParam("world", "torque_delay_ms", 3.0))
    lab.apply(SwitchSession(scenario="polish"))
    assert [(o.group, o.field) for o in lab.overrides] == [("drag", "max_force_n")]
    assert lab.session.drag.max_force_n == 55.0 and lab.session.world.torque_delay_steps == 0


def _body_of_joint(world, joint_name: str) -> int:
    return int(world.model.jnt_bodyid[world.model.joint(joint_name).id])


@pytest.mark.parametrize("scenario", ["free", "polish", "compliance", "limit-drop", "mass-drop"])
def test_the_largest_drag_sinks_no_joint_beyond_its_hard_stop_and_says_it_overpowers_the_arm(scenario):
    """A 300 N pull (the GUI's largest drag) at the TCP and at the elbow: every joint stays within
    HARD_STOP_GIVE_RAD of its mechanical stop, and a notice and the status name an overpowered joint."""
    from app.live.frames import make_status
    from app.sim.world import HARD_STOP_BEYOND_RAD, HARD_STOP_GIVE_RAD

    lab = _lab(scenario)
    robot = lab.session.robot
    lab.apply(SetParam("drag", "max_force_n", 300.0))
    worst = 0.0
    said = []
    status_said = ""
    for where, pull in (("tcp", (-1.0, 0.0, 0.0)), ("elbow", (0.0, 0.0, -1.0))):
        lab.apply(Reset())
        w = lab.session.world
        body = w.wrist_body if where == "tcp" else _body_of_joint(w, robot.joint_names[3])
        p0 = w.site_pose(w.tcp_site)[0] if where == "tcp" else w.data.xpos[body].copy()
        lab.apply(DragCommand("grab", client_id=1, body_name=w.model.body(body).name, point_world=tuple(p0)))
        lab.apply(DragCommand("move", client_id=1, target_world=tuple(p0 + 2.0 * np.array(pull))))
        n0 = len(lab.notice_log)
        for _ in range(30):  # 1.5 s in bursts of 50 steps, as the loop runs it
            q_max = np.full(robot.nq, -np.inf)

            def track(rec, q_max=q_max):
                np.maximum(q_max, np.maximum(rec.q - robot.q_upper, robot.q_lower - rec.q), out=q_max)

            assert not lab.session.run(steps=50, record=track).halted
            lab.overpowering.check(lab.session)
            worst = max(worst, float(np.max(np.where(robot.endless, 0.0, q_max))))
            status_said = status_said or make_status(lab).overpowered
        said += [n.body for n in list(lab.notice_log)[n0:] if n.title == "Overpowered"]
    print(f"{scenario}: worst {worst - HARD_STOP_BEYOND_RAD:+.4f} rad into a hard stop; {said}")
    assert worst <= HARD_STOP_BEYOND_RAD + HARD_STOP_GIVE_RAD
    assert said and all(re.search(r"joint \d", s) for s in said) and re.search(r"joint \d", status_said)


def test_advance_looks_for_an_overpowered_joint_every_ten_steps_and_at_once_after_a_reset(monkeypatch):
    """Paced, the loop advances two steps at a time; the look for an overpowered joint (World.overpowered,
    a Python loop over the joints) runs once per OVERPOWERED_CHECK_STEPS steps, not once per burst, and
    at the first burst after a reset (so a new run is looked at from its start)."""
    lab = _lab()
    looks: list[int] = []
    check = lab.overpowering.check
    monkeypatch.setattr(lab.overpowering, "check", lambda s: (looks.append(lab.total_steps), check(s))[1])
    for _ in range(50):
        lab.advance(2)
    assert OVERPOWERED_CHECK_STEPS == 10
    assert looks == list(range(2, 101, 10))  # 100 steps: 10 looks, 10 steps apart
    lab.apply(Reset())
    lab.advance(2)
    assert looks[-1] == 102 and len(looks) == 11


def test_every_command_type_has_a_handler_and_an_unknown_one_is_refused_with_a_notice():
    import typing

    from app.core.commands import Command
    from app.live.lab import HANDLERS
    from app.live.run_flags import HANDLERS as FLAG_HANDLERS

    assert set(typing.get_args(Command)) == set(HANDLERS) | set(FLAG_HANDLERS) and not set(HANDLERS) & set(
        FLAG_HANDLERS
    )
    lab = _lab()
    lab.apply(object())  # type: ignore[arg-type]
    assert lab.notice_log[-1].title == "Refused" and "unknown command" in lab.notice_log[-1].body


def test_the_session_is_the_one_store_of_overrides_and_a_rebuild_replays_it_in_order():
    """The lab's overrides are the session's changes; a robot switch (a new session) gets them in
    order, and `Session.overrides()` keeps each field's last value."""
    lab = _lab()
    lab.apply(SetParam("drag", "max_force_n", 40.0))
    lab.apply(SetParam("joint_hold", "stiffness", 500.0))
    lab.apply(SetParam("drag", "max_force_n", 42.0))
    assert lab.overrides == lab.session.changes and len(lab.overrides) == 3
    lab.apply(SwitchSession(robot="gen3"))
    assert lab.session.robot.name == "gen3"
    assert [(o.group, o.field, o.value) for o in lab.overrides] == [
        ("drag", "max_force_n", 40.0),
        ("joint_hold", "stiffness", 500.0),
        ("drag", "max_force_n", 42.0),
    ]
    assert lab.session.drag.max_force_n == 42.0 and lab.session.params()["joint_hold"].stiffness == 500.0
    assert lab.session.overrides() == {"drag": {"max_force_n": 42.0}, "joint_hold": {"stiffness": 500.0}}
