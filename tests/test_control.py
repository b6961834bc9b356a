"""The control loop (phri.control): its tick, the safety layer's limits and the watchdog's stops,
over a fake in-memory arm whose state the tests script, and over the PyBullet JACO2 in a short
real episode."""

from __future__ import annotations

import gc
import math
from collections.abc import Callable
from dataclasses import replace
from importlib import resources
from pathlib import Path

import numpy as np
import pytest
from fake_arm import FakeArm
from test_sim import shortened  # the study's tasks cut short, as the simulation tests use them

import phri
from phri.config import TaskSafety, load_task
from phri.control import (
    SAFETY_LIMITS,
    STOP_REASONS,
    Backend,
    ControlLoop,
    RobotState,
    SafetyLimits,
    StopEvent,
    safety_limits,
)
from phri.exceptions import (
    ConfigError,
    ConnectionLostError,
    InvalidParameterError,
    RobotFaultError,
    SafetyStopError,
)
from phri.robots import SafetySpec

#: The table task's start pose [rad]: inside every limit, its hand above the table.
START = load_task("table").start
PERIOD = 1e-3
JACO2 = phri.Robot.jaco2()


class StillLearner:
    """A learner whose reference is the start pose, counting observe calls."""

    def __init__(self, fail_at: float | None = None) -> None:
        self.observed: list[float] = []
        self.fail_at = fail_at

    def observe(self, t: float, tau_measured: np.ndarray) -> tuple[bool, bool, bool]:
        if self.fail_at is not None and t >= self.fail_at:
            raise RuntimeError("the learner failed")
        self.observed.append(t)
        return False, False, False

    def reference(self, t: float, *, out: tuple[np.ndarray, np.ndarray, np.ndarray]):
        out[0][:] = START
        out[1][:] = 0.0
        out[2][:] = 0.0
        return out


def limits(**changes) -> SafetyLimits:
    """The JACO2's limits for the table task (its tool box), with `changes`."""
    return replace(safety_limits(JACO2, "jaco2", load_task("table")), **changes)


def loop_over(arm: FakeArm, learner=None, **kwargs) -> ControlLoop:
    return ControlLoop(
        arm,
        learner or StillLearner(),
        phri.ImpedanceController(JACO2),
        kwargs.pop("limits", limits()),
        **kwargs,
    )


def at(tick: int, change: Callable[[RobotState], None]) -> Callable[[int, RobotState], None]:
    """A script changing the state from tick `tick` on."""

    def script(k: int, state: RobotState) -> None:
        if k >= tick:
            change(state)

    return script


def test_the_fake_arm_is_a_backend() -> None:
    assert isinstance(FakeArm(), Backend)
    with pytest.raises(InvalidParameterError, match="backend must implement"):
        ControlLoop(object(), StillLearner(), phri.ImpedanceController(JACO2), limits())  # type: ignore[arg-type]


def test_a_quiet_motion_observes_every_tick_logs_at_the_log_rate_and_stops_the_arm() -> None:
    arm, learner = FakeArm(), StillLearner()
    loop = loop_over(arm, learner, log_rate=100.0)
    result = loop.run(START, 0.2)
    assert result.stop is None and result.error is None and result.held == 0.0
    assert result.ticks == 201 and len(learner.observed) == 201 and len(arm.commands) == 201
    np.testing.assert_allclose(learner.observed, np.arange(201) * PERIOD)
    np.testing.assert_allclose(result.log["t"], np.arange(21) * 0.01, atol=1e-12)
    assert set(result.log) == {"t", "q", "qd", "q_ref", "tau", "tau_ext", "wall_force"}
    # At its reference and at rest, the law is gravity compensation: an arm without it is
    # commanded g(q).
    np.testing.assert_allclose(arm.commands[0], JACO2.gravity(START), atol=1e-9)
    assert arm.stops == 1
    assert not result.torque_clips.any() and not result.rate_clips.any()


def test_an_arm_that_compensates_gravity_is_commanded_the_torque_less_g() -> None:
    arm = FakeArm(gravity_compensated=True)
    result = loop_over(arm).run(START, 0.05)
    np.testing.assert_allclose(arm.commands[-1], np.zeros(7), atol=1e-9)
    # The log's torque is the joint torque the arm applies: g(q) included.
    np.testing.assert_allclose(result.log["tau"][-1], JACO2.gravity(START), atol=1e-9)


def test_the_loop_needs_the_laws_gravity_and_valid_settings() -> None:
    with pytest.raises(InvalidParameterError, match="gravity_compensation=True"):
        ControlLoop(
            FakeArm(), StillLearner(), phri.ImpedanceController(JACO2, gravity_compensation=False), limits()
        )
    for kwargs, match in (
        ({"hold_time": -1.0}, "hold_time"),
        ({"hold_time": math.nan}, "hold_time"),
        ({"late_ticks": 0}, "late_ticks"),
        ({"log_rate": 2000.0}, "log_rate"),
    ):
        with pytest.raises(InvalidParameterError, match=match):
            loop_over(FakeArm(), **kwargs)
    with pytest.raises(InvalidParameterError, match="duration"):
        loop_over(FakeArm()).run(START, -1.0)
    with pytest.raises(InvalidParameterError, match="q_start"):
        loop_over(FakeArm()).run(np.zeros(6), 1.0)


@pytest.mark.parametrize(
    "q_start", [START + 1j, np.ma.masked_array(START, mask=START > 3), [1.0, [2.0]], START.astype(str)]
)
def test_a_start_that_is_not_real_numbers_is_refused_not_cast(q_start) -> None:
    # Found by the fuzz suite: a complex start lost its imaginary part with only a warning.
    with pytest.raises(TypeError, match="^q_start must be an array of real numbers, got "):
        loop_over(FakeArm()).run(q_start, 1.0)


def test_a_run_whose_log_would_not_fit_is_refused_before_it_starts() -> None:
    # Found by the fuzz suite: hold_time=1e12 asked numpy for a 7 TiB log.
    with pytest.raises(InvalidParameterError, match=r"^duration \+ hold_time .* more than 1000000 rows"):
        loop_over(FakeArm(), hold_time=1e12).run(START, 1.0)
    with pytest.raises(InvalidParameterError, match=r"^duration \+ hold_time"):
        loop_over(FakeArm()).run(START, 1.7e308)


@pytest.mark.parametrize("value", [-1, 2**32, 10**100])
def test_a_late_ticks_count_out_of_range_names_the_argument(value: int) -> None:
    # Not PyO3's bare OverflowError ("out of range integral type conversion attempted").
    match = r"^late_ticks must be an integer in \[0, 4294967295\], got "
    with pytest.raises(InvalidParameterError, match=match):
        limits().layer(JACO2, period=PERIOD, gravity_compensated=False, late_ticks=value)
    if value > 0:  # the loop's own check refuses the rest
        with pytest.raises(InvalidParameterError, match=match):
            loop_over(FakeArm(), late_ticks=value)


def _bump(joint: int, value: float, attribute: str) -> Callable[[RobotState], None]:
    def change(state: RobotState) -> None:
        getattr(state, attribute)[joint] = value

    return change


def _hand_down(state: RobotState) -> None:
    # Joint 2 turned until the hand is below the table's top (z = -0.1016): z = -0.29 m.
    state.q[1] = START[1] - 1.2


#: (limit, script from tick 50, the state's quantity, joint or axis, limits that disable the check)
LIMIT_CASES = {
    "joint_position": (at(50, _bump(3, 0.55, "q")), "q", 3, {"position_lower": np.full(7, -np.inf)}),
    "joint_velocity": (at(50, _bump(4, -1.9, "qd")), "qd", 4, {"velocity": np.full(7, 10.0)}),
    "tool_box": (at(50, _hand_down), "tool_position", 2, {"tool_box": None}),
    "non_finite": (at(50, _bump(3, math.nan, "tau_ext")), "tau_ext", 3, None),
}


@pytest.mark.parametrize("limit", list(LIMIT_CASES))
def test_each_limit_crossed_stops_the_arm_which_holds_then_ends_the_motion(limit: str) -> None:
    script, quantity, index, _ = LIMIT_CASES[limit]
    arm = FakeArm(script=script)
    loop = loop_over(arm, hold_time=0.1)
    with pytest.raises(SafetyStopError) as raised:
        loop.run(START, 1.0)
    result = loop.result  # the log survives the stop
    event = raised.value.event
    assert isinstance(event, StopEvent) and event is result.stop
    assert (event.reason, event.quantity, event.index, event.tick) == (limit, quantity, index, 50)
    assert event.t == pytest.approx(0.05) and event.reason in STOP_REASONS
    assert event.message and (limit == "non_finite" or math.isfinite(event.bound))
    # It held for the hold time (robot time), then ended the motion: stop() once, no more ticks.
    assert result.held == pytest.approx(0.1, abs=1.5 * PERIOD)
    assert result.ticks == len(arm.commands) == 50 + 101
    assert arm.stops == 1
    # The hold's reference is the position at the stop, at rest; the log runs through the hold.
    stopped = result.log["t"] >= 0.05 - 1e-9
    np.testing.assert_array_equal(result.log["q_ref"][stopped], np.tile(event.q, (stopped.sum(), 1)))
    assert result.log["t"][-1] == pytest.approx(0.15)


@pytest.mark.parametrize("limit", [k for k, case in LIMIT_CASES.items() if case[3] is not None])
def test_without_its_limit_the_same_state_runs_to_the_end(limit: str) -> None:
    """The stop comes from the check: with that limit disabled the same scripted state runs on."""
    script, _, _, disabled = LIMIT_CASES[limit]
    result = loop_over(FakeArm(script=script), limits=limits(**disabled)).run(START, 0.2)
    assert result.stop is None and result.ticks == 201


def test_a_stop_can_be_returned_instead_of_raised() -> None:
    arm = FakeArm(script=LIMIT_CASES["joint_velocity"][0])
    result = loop_over(arm, hold_time=0.0).run(START, 1.0, check=False)
    assert result.stop is not None and result.stop.reason == "joint_velocity"
    assert isinstance(result.error, SafetyStopError) and result.error.event is result.stop
    with pytest.raises(SafetyStopError, match="joint_velocity"):
        result.raise_for_stop()


def test_a_non_finite_position_ends_the_motion_at_once_without_a_command() -> None:
    arm = FakeArm(script=at(30, _bump(2, math.inf, "q")))
    result = loop_over(arm).run(START, 1.0, check=False)
    assert result.stop is not None and (result.stop.reason, result.stop.quantity) == ("non_finite", "q")
    assert result.held == 0.0 and len(arm.commands) == 30 and arm.stops == 1
    assert all(np.isfinite(c).all() for c in arm.commands)


@pytest.mark.parametrize(("field", "value"), [("q", 1e12), ("qd", 1e300), ("tau_ext", -1e300)])
def test_an_absurd_finite_reading_stops_the_arm_as_a_non_finite_one_does(field: str, value: float) -> None:
    """Found by the fuzz suite: a reading beyond ±1e9 passed the safety layer (or crossed a limit),
    and then the learner or the hold's impedance law refused it with an error instead of a stop."""
    arm = FakeArm(script=at(30, _bump(1, value, field)))
    result = loop_over(arm).run(START, 1.0, check=False)
    assert result.stop is not None and (result.stop.reason, result.stop.quantity) == ("non_finite", field)
    assert "beyond ±1e9" in result.stop.message and arm.stops == 1
    # A position or velocity reading cannot be held from; the person's torque can.
    assert (result.held == 0.0) == (field != "tau_ext")
    assert all(np.isfinite(c).all() for c in arm.commands)


def test_a_lost_connection_ends_the_motion_and_keeps_the_log() -> None:
    def fail(k: int) -> None:
        if k == 120:
            raise ConnectionLostError("host '127.0.0.1': the robot stopped answering")

    arm = FakeArm(fail=fail)
    loop = loop_over(arm)
    with pytest.raises(SafetyStopError, match="stopped answering") as raised:
        loop.run(START, 1.0)
    event = raised.value.event
    assert event.reason == "connection_lost" and event.t == pytest.approx(0.119)  # the last state read
    assert len(arm.commands) == 120 and arm.stops == 1 and loop.result.held == 0.0
    assert len(loop.result.log["t"]) == 12


def test_the_robots_own_fault_ends_the_motion() -> None:
    def fault(state: RobotState) -> None:
        state.fault = "the robot reports robot mode Reflex; errors: joint_position_limits_violation"

    arm = FakeArm(script=at(10, fault))
    result = loop_over(arm).run(START, 1.0, check=False)
    assert result.stop is not None and result.stop.reason == "robot_fault"
    assert "Reflex" in result.stop.message and len(arm.commands) == 10 and arm.stops == 1

    def refused(k: int) -> None:
        if k == 5:
            raise RobotFaultError("the robot aborted control: communication_constraints_violation")

    arm = FakeArm(fail_write=refused)
    result = loop_over(arm).run(START, 1.0, check=False)
    assert result.stop is not None and result.stop.reason == "robot_fault" and arm.stops == 1


def _clock(times: Callable[[int], float]) -> Callable[[int, RobotState], None]:
    def script(k: int, state: RobotState) -> None:
        state.t = times(k)

    return script


@pytest.mark.parametrize("late_ticks", [3, 5])
def test_n_late_ticks_in_a_row_stop_the_arm_on_the_robots_clock(late_ticks: int) -> None:
    # From tick 20 on, every tick comes 2 periods after the previous one.
    arm = FakeArm(script=_clock(lambda k: k * PERIOD if k <= 20 else (20 + 2 * (k - 20)) * PERIOD))
    result = loop_over(arm, late_ticks=late_ticks, hold_time=0.01).run(START, 1.0, check=False)
    assert result.stop is not None and result.stop.reason == "late_ticks"
    assert result.stop.tick == 20 + late_ticks and result.stop.index == late_ticks
    assert result.stop.value == pytest.approx(2 * PERIOD)
    # The arm still answers: it holds (late ticks go on, on the robot's clock) and then stops.
    assert result.held == pytest.approx(0.01, abs=2 * PERIOD) and arm.stops == 1


def test_single_late_ticks_do_not_stop_the_arm() -> None:
    # Every tenth tick is late; never two in a row.
    arm = FakeArm(script=_clock(lambda k: (k + k // 10) * PERIOD))
    result = loop_over(arm).run(START, 0.3)
    assert result.stop is None


def test_a_clock_that_does_not_advance_ends_the_motion() -> None:
    arm = FakeArm(script=_clock(lambda k: min(k, 40) * PERIOD))
    result = loop_over(arm).run(START, 1.0, check=False)
    assert result.stop is not None and result.stop.reason == "clock" and result.held == 0.0
    assert len(arm.commands) == 41


def _table_learner(duration: float, waypoints: int = 5, **kwargs) -> phri.Learner:
    """A phri.Learner for the table task cut to `duration` seconds (it refuses times past it), its
    plan `waypoints` long (a push deforms it with 11 or more: the deformation's window is 5)."""
    from types import SimpleNamespace

    from phri.sim import Planner

    task = shortened(load_task("table"), duration, waypoints)
    planner = Planner(task, SimpleNamespace(model=JACO2))  # type: ignore[arg-type]
    update = phri.WeightUpdate(task.vector("step"), task.vector("lower"), task.vector("upper"))
    return phri.Learner(
        planner.features, phri.Deformation(), update, phri.InteractionDetector(), planner.optimizer,
        task.vector("initial"), task.start, task.goal, duration=duration, **kwargs,
    )  # fmt: skip


def test_a_failed_replan_worker_does_not_end_the_motion(caplog) -> None:
    # The learner's contract: a failed worker (here a panic, a bug in phri) is a ReplanWorkerError
    # once and the arm keeps the plan it tracks. The loop goes on with it, counting the failure,
    # rather than end the motion abruptly without a hold or a StopEvent.
    learner = _table_learner(1.0, 11, replan_latency=0.01)
    plan = learner.plan
    learner._debug_panic_worker()
    push = np.array([0.0, 30.0, 0.0, 0.0, 0.0, 0.0, 0.0])  # beyond joint 2's 8 N·m threshold
    arm = FakeArm(script=lambda k, state: state.tau_ext.__setitem__(slice(None), push if k == 300 else 0.0))
    result = loop_over(arm, learner).run(START, 1.0)
    assert result.stop is None and result.ticks == 1001 and arm.stops == 1
    assert result.replan_failures == 1
    assert "panicked" in caplog.text
    assert len(learner.history()) == 1 and len(learner.history().rejected) == 1
    np.testing.assert_array_equal(learner.plan, plan)


def test_a_late_last_tick_past_the_tasks_end_still_finishes_the_motion() -> None:
    # One late tick (50 ms: the robot's clock jumps) at the motion's end puts the last tick past
    # the task's end; single late ticks do not stop the arm, and the learner must not be handed a
    # time it refuses (past duration + Learner.TIME_SLACK), which would end the motion with an error.
    duration = 0.2
    arm = FakeArm(script=_clock(lambda k: k * PERIOD if k < 195 else (k + 50) * PERIOD))
    result = loop_over(arm, _table_learner(duration)).run(START, duration)
    assert result.stop is None and result.ticks == 196 and len(arm.commands) == 196
    assert arm.stops == 1


def test_torques_beyond_the_limits_are_clipped_and_counted() -> None:
    # A reference 0.5 rad away asks joint 2 for 150 N·m of spring torque.
    class Far(StillLearner):
        def reference(self, t, *, out):
            super().reference(t, out=out)
            out[0][1] += 0.5
            return out

    tight = limits(torque=np.full(7, 10.0))
    arm = FakeArm()
    result = loop_over(arm, Far(), limits=tight).run(START, 0.05)
    assert result.torque_clips[1] == 51 and result.stop is None
    assert max(abs(c[1]) for c in arm.commands) == pytest.approx(10.0)
    assert np.abs(result.log["tau"]).max() <= 10.0 + 1e-12


def test_the_commands_rate_is_limited_and_counted() -> None:
    class Step(StillLearner):
        """The reference jumps 1 rad on joint 4 at t = 0.02 s: a 15 N·m step of the spring."""

        def reference(self, t, *, out):
            super().reference(t, out=out)
            if t >= 0.02 - 1e-9:
                out[0][3] += 1.0
            return out

    for rate, clipped in ((100.0, True), (1e6, False)):  # 0.1 N·m per tick; and no real limit
        arm = FakeArm(gravity_compensated=True)
        result = loop_over(arm, Step(), limits=limits(torque_rate=np.full(7, rate))).run(START, 0.05)
        steps = np.abs(np.diff(np.array(arm.commands), axis=0))
        assert (result.rate_clips[3] > 0) == clipped
        if clipped:
            assert steps.max() <= rate * PERIOD + 1e-9
        else:
            assert steps.max() > 10.0


@pytest.mark.parametrize("gravity_compensated", [False, True])
def test_the_first_command_is_rate_limited_from_what_the_arm_holds_at_rest(gravity_compensated: bool) -> None:
    # A reference 0.5 rad away on joint 2 asks for a large spring torque at once. The first command
    # may move at most one rate step from what the arm applies at rest where it starts: nothing for
    # an arm that compensates gravity, g(q) for one that does not (a lab's own arm, not only PyBullet).
    class Far(StillLearner):
        def reference(self, t, *, out):
            super().reference(t, out=out)
            out[0][1] += 0.5
            return out

    rate = 100.0  # N·m/s: 0.1 N·m per tick
    arm = FakeArm(gravity_compensated=gravity_compensated)
    result = loop_over(arm, Far(), limits=limits(torque_rate=np.full(7, rate))).run(START, 0.01)
    at_rest = np.zeros(7) if gravity_compensated else JACO2.gravity(START)
    assert np.abs(arm.commands[0] - at_rest).max() <= rate * PERIOD + 1e-9
    assert result.rate_clips[1] == len(arm.commands)


def test_any_other_error_ends_the_motion_is_raised_and_keeps_the_log_and_the_collector() -> None:
    enabled, frozen = gc.isenabled(), gc.get_freeze_count()
    arm = FakeArm()
    loop = loop_over(arm, StillLearner(fail_at=0.1))
    with pytest.raises(RuntimeError, match="learner failed"):
        loop.run(START, 1.0)
    assert arm.stops == 1 and len(loop.result.log["t"]) == 10 and loop.result.stop is None
    assert gc.isenabled() == enabled and gc.get_freeze_count() == frozen


def test_the_collector_is_off_and_frozen_during_the_ticks_and_restored_after() -> None:
    seen = []
    arm = FakeArm(script=lambda k, s: seen.append((gc.isenabled(), gc.get_freeze_count() > 0)))
    enabled, frozen = gc.isenabled(), gc.get_freeze_count()
    loop_over(arm).run(START, 0.01)
    assert seen and all(not on and frozen_now for on, frozen_now in seen)
    assert gc.isenabled() == enabled and gc.get_freeze_count() == frozen
    arm = FakeArm(script=LIMIT_CASES["joint_velocity"][0])
    with pytest.raises(SafetyStopError):
        loop_over(arm).run(START, 1.0)
    assert gc.isenabled() == enabled and gc.get_freeze_count() == frozen


def test_a_stop_round_trips_through_log_arrays() -> None:
    result = loop_over(FakeArm(script=LIMIT_CASES["tool_box"][0])).run(START, 1.0, check=False)
    event = result.stop
    assert event is not None
    arrays = event.arrays()
    assert tuple(arrays) == StopEvent.KEYS == tuple(StopEvent.empty_arrays(7))
    back = StopEvent.from_arrays(arrays)
    assert back is not None and (back.reason, back.index, back.value, back.bound) == (
        event.reason, event.index, event.value, event.bound,
    )  # fmt: skip
    np.testing.assert_array_equal(back.q, event.q)
    assert StopEvent.from_arrays(StopEvent.empty_arrays(7)) is None


# -- the limits: robot descriptions and task files ----------------------------------------------


def test_the_shipped_robots_and_tasks_give_complete_limits() -> None:
    assert set(SAFETY_LIMITS) <= set(STOP_REASONS)
    for name in phri.task_names():
        task = load_task(name)
        robot = phri.Robot.from_description(task.robot)
        lim = safety_limits(robot, task.robot, task)
        assert lim.tool_box is not None, f"{name}: every shipped task has a tool box"
        assert (lim.torque_rate > 0).all() and (lim.velocity > 0).all()
        # Start and goal lie inside the limits, the hand inside the box.
        for q in (task.start, task.goal):
            finite = np.isfinite(lim.position_lower)
            assert (q[finite] >= lim.position_lower[finite]).all(), name
            assert (q[finite] <= lim.position_upper[finite]).all(), name
            hand = robot.frame_pose(lim.tool, q)[:3, 3]
            assert (hand >= lim.tool_box[0]).all() and (hand <= lim.tool_box[1]).all(), name
    fr3 = safety_limits(phri.Robot.fr3(), "fr3")
    np.testing.assert_array_equal(fr3.torque_rate, np.full(7, 1000.0))  # libfranka's kMaxTorqueRate
    np.testing.assert_array_equal(fr3.velocity, phri.Robot.fr3().velocity_limits)  # the URDF's


def _description(tmp_path: Path, safety: str) -> Path:
    shipped = phri.robots.load("jaco2")
    head = Path(shipped.source).read_text(encoding="utf-8").split("\n[safety]")[0] + "\n"
    folder = tmp_path / "robot"
    folder.mkdir(exist_ok=True)
    for f in Path(shipped.source).parent.iterdir():
        if f.suffix == ".urdf":
            (folder / f.name).write_bytes(f.read_bytes())
    path = folder / "robot.toml"
    path.write_text(head + safety, encoding="utf-8")
    return path


def test_a_description_without_a_torque_rate_limit_cannot_run_the_loop(tmp_path) -> None:
    path = _description(tmp_path, "[safety]\nposition_margin = 0.05\n")
    with pytest.raises(ConfigError, match="torque_rate_limit"):
        safety_limits(JACO2, path)


@pytest.mark.parametrize(
    ("safety", "match"),
    [
        ("[safety]\ntorque_rate_limit = -1.0\n", "torque_rate_limit"),
        ("[safety]\ntorque_rate_limit = [1.0, 2.0]\n", "one per joint"),
        ("[safety]\ntorque_rate_limit = 1.0\ntorque_limits = 500.0\n", "URDF's efforts"),
        ("[safety]\ntorque_rate_limit = 1.0\nposition_margin = 3.0\n", "wider than half"),
        ("[safety]\ntorque_rate_limit = 1.0\nspeed = 1.0\n", "unknown key 'safety.speed'"),
        ("[safety]\ntorque_rate_limit = 'fast'\n", "torque_rate_limit"),
    ],
)
def test_bad_safety_tables_are_clear_errors(tmp_path, safety: str, match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        safety_limits(JACO2, _description(tmp_path, safety))


def test_a_task_may_tighten_the_robots_limits_but_never_loosen_them() -> None:
    task = load_task("table")
    tighter = replace(
        task, safety=TaskSafety(task.safety.tool_box, SafetySpec("task.toml", velocity_limits=0.3))
    )
    np.testing.assert_array_equal(safety_limits(JACO2, "jaco2", tighter).velocity, np.full(7, 0.3))
    looser = replace(task, safety=TaskSafety(None, SafetySpec("task.toml", torque_rate_limit=1e5)))
    with pytest.raises(ConfigError, match="may only tighten"):
        safety_limits(JACO2, "jaco2", looser)
    narrower = replace(task, safety=TaskSafety(None, SafetySpec("task.toml", position_margin=0.01)))
    with pytest.raises(ConfigError, match="position_margin"):
        safety_limits(JACO2, "jaco2", narrower)


@pytest.mark.parametrize(
    ("table", "match"),
    [
        ("tool_box = { lower = [0, 0, 0], upper = [1, 1, 0] }", "lower < upper"),
        ("tool_box = [0, 0, 0]", "tool_box"),
        ("tool_box = { lower = [0, 0], upper = [1, 1, 1] }", "tool_box.lower"),
        ("tool_box = { lower = [0, 0, 0], upper = [1, 1, 1], side = 2 }", "unknown key"),
        ("velocity_limits = 0", "velocity_limits"),
    ],
)
def test_bad_task_safety_tables_are_clear_errors(tmp_path, table: str, match: str) -> None:
    source = resources.files("phri").joinpath("tasks", "table.toml")
    text = source.read_text(encoding="utf-8").split("\n[safety]")[0] + "\n" + "[safety]\n" + table + "\n"
    path = tmp_path / "task.toml"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(ConfigError, match=match):
        load_task(path)


# -- the PyBullet backend, in short real episodes ----------------------------------------------


class CountingRng:
    """A generator that counts its normal() draws (and draws them from a real one)."""

    def __init__(self, seed: int) -> None:
        self.rng, self.draws = np.random.default_rng(seed), 0

    def normal(self, *args, **kwargs):
        self.draws += 1
        return self.rng.normal(*args, **kwargs)


def test_the_pybullet_backend_measures_the_push_at_the_sample_rate_only(world) -> None:
    from phri.sim.backend import PyBulletBackend

    class SteadyPush:
        """A person who pushes the hand down with 10 N and twists it with 0.5 N·m, always."""

        def wrench(self, t: float, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            return np.array([0.0, 0.0, -10.0]), np.array([0.5, 0.0, 0.0])

    task = shortened(load_task("table"), 1.0, 5)
    world.set_scene(task.scene)
    rng = CountingRng(3)
    person = SteadyPush()
    backend = PyBulletBackend(world, participant=person, sample_rate=10.0, sensor_noise=0.1, rng=rng)  # type: ignore[arg-type]
    assert isinstance(backend, Backend) and not backend.gravity_compensated
    state, held = backend.start(task.start), []
    for k in range(1, 251):
        backend.write(world.model.gravity(state.q))
        state = backend.read()
        held.append(state.tau_ext.copy())
        if k == 200:  # the third sample instant: the measurement is noise + Jᵀ·wrench
            assert backend.push is not None, "the person pushes"
            wrench = np.concatenate(backend.push)
            jacobian = world.model.jacobian(phri.Robot.jaco2().hand_frame, state.q)
    # One draw per sample instant (t = 0, 0.1, 0.2): the sensor's stream is the study's.
    assert rng.draws == 3 and state.t == pytest.approx(0.25)
    same = np.random.default_rng(3)
    noise = [same.normal(0.0, 0.1, 7) for _ in range(3)][-1]
    np.testing.assert_allclose(held[199], noise + jacobian.T @ wrench, rtol=1e-12, atol=1e-12)
    # Held between samples.
    np.testing.assert_array_equal(held[199], held[248])
    with pytest.raises(InvalidParameterError, match="sample_rate"):
        PyBulletBackend(world, sample_rate=333.0)


@pytest.mark.slow
def test_a_short_episode_runs_on_the_loop_and_logs_no_stop(world) -> None:
    from phri.sim import EpisodeConfig, ParticipantParams, Planner
    from phri.sim.episode import simulate_episode

    task = shortened(load_task("table"), 2.0, 7)
    person = ParticipantParams(tolerance=0.01, delay=0.05)
    result, error = simulate_episode(
        task, world, person, EpisodeConfig(), seed=1, planner=Planner(task, world)
    )
    assert error is None and result.stop is None
    log = result.log_arrays
    assert len(log["t"]) == 201 and len(log["stop_reason"]) == 0
    assert not log["torque_clips"].any() and not log["rate_clips"].any()
    assert np.any(log["push"] != 0), "the person pushed"
    assert len(log["interaction_t"]) > 0, "and the learner saw it"


@pytest.mark.slow
def test_a_safety_stop_in_an_episode_holds_the_arm_and_writes_the_log_with_the_stop(world, tmp_path) -> None:
    from phri.sim import EpisodeConfig, ParticipantParams, Planner, run_episode

    short = shortened(load_task("table"), 2.0, 7)
    # The plan moves joints 1, 3 and 6 at up to 0.22 rad/s: a task limit of 0.1 rad/s stops it.
    slow = replace(
        short, safety=TaskSafety(short.safety.tool_box, SafetySpec("slow.toml", velocity_limits=0.1))
    )
    nobody = ParticipantParams(tolerance=1e9, tilt_tolerance=1e9)
    path = tmp_path / "stopped.npz"
    with pytest.raises(SafetyStopError, match="joint_velocity") as raised:
        run_episode(slow, world, nobody, EpisodeConfig(), planner=Planner(short, world), log_path=path)
    event = raised.value.event
    assert event.reason == "joint_velocity" and abs(event.value) > 0.1 and 0 < event.t < 2.0
    with np.load(path) as log:
        back = StopEvent.from_arrays(log)
        assert back is not None and back.reason == "joint_velocity" and back.t == event.t
        t, q, qd, q_ref = log["t"], log["q"], log["qd"], log["q_ref"]
    # The log runs through the hold (0.5 s after the stop), the reference fixed at the stop's q.
    holding = t >= event.t
    assert t[-1] == pytest.approx(event.t + 0.5, abs=0.011)
    np.testing.assert_array_equal(q_ref[holding], np.tile(event.q, (holding.sum(), 1)))
    # And the impedance law holds the arm there: it comes to rest within millimetres of radians.
    assert np.abs(q[-1] - event.q).max() < 0.01
    assert np.abs(qd[-1]).max() < 0.02


# -- the loop over libfranka's protocol ---------------------------------------------------------


def test_the_loop_holds_a_franka_over_libfrankas_protocol() -> None:
    """The same loop over FrankaBackend against franky-sim (on loopback, slowed down): the robot
    compensates gravity, so the command is the law's torque less g(q), its rate limited from zero."""
    pytest.importorskip("pylibfranka", reason="phri[franka] is part of make dev")
    from phri.franka import FrankaBackend
    from phri.franka.sim_server import SimServer

    robot = phri.Robot.fr3()

    class Recording(FrankaBackend):
        """Remembers the first state: the pose the learner below holds."""

        def start(self, q_start: np.ndarray) -> RobotState:
            self.first = super().start(q_start)
            return self.first

    class HoldFirst(StillLearner):
        def reference(self, t, *, out):
            out[0][:] = backend.first.q
            out[1][:] = 0.0
            out[2][:] = 0.0
            return out

    # libfranka's joint impedance example's gains [N·m/rad], [N·m·s/rad].
    controller = phri.ImpedanceController(
        robot, stiffness=[600, 600, 600, 600, 250, 150, 50], damping=[50, 50, 50, 20, 20, 20, 10]
    )
    with SimServer("127.0.0.61", realtime=4.0) as server:
        backend = Recording(server.host, robot, realtime=False)
        loop = ControlLoop(backend, HoldFirst(), controller, safety_limits(robot, "fr3"))
        try:
            result = loop.run(np.zeros(7), 0.3)
        except ConnectionLostError:
            # libfranka's own handshake timeout, seen once with the whole suite loading a 2-core
            # machine: connect once more (a lost connection mid-run is a stop, not this error).
            result = loop.run(np.zeros(7), 0.3)
    assert result.stop is None and result.ticks >= 290
    log = result.log
    assert np.all(np.isfinite(log["tau"])) and np.all(np.isfinite(log["tau_ext"]))
    np.testing.assert_allclose(log["q"], np.tile(backend.first.q, (len(log["q"]), 1)), atol=0.01)
    # The torque applied is g(q) plus the small spring and damper torques: the command held it.
    gravity = np.array([robot.gravity(q) for q in log["q"]])
    assert np.abs(log["tau"] - gravity).max() < 5.0


def test_the_python_tick_bench_runs(capsys, monkeypatch) -> None:
    """benches/python_step.py (make bench-python) on a few calls, so the bench behind the Timing
    section of docs/control.md does not rot: every row is printed, and the pushed ticks deformed the
    learner's plan."""
    import re
    import sys

    from conftest import load_bench

    bench = load_bench("python_step")
    monkeypatch.setattr(sys, "argv", ["python_step.py", "--calls", "1000"])
    try:
        bench.main()
    finally:
        gc.enable()  # the bench freezes and disables the collector, as a control loop does
        gc.unfreeze()
    out = capsys.readouterr().out
    rows = ("ControlLoop tick, control-thread part", "the same, pushed every 100th tick", "the pushed ticks")
    for row in rows:
        assert row in out, out
    # The pushes early in the task all deform the plan (the control side's part, deterministic).
    deformed = re.search(r"\((\d+) pushes deformed the plan", out)
    assert deformed is not None and int(deformed.group(1)) >= 5, out
