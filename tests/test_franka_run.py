"""An FR3 episode over the libfranka protocol, ``phri run`` and the live study, against phri's scene
server (franky-sim's MuJoCo FR3 with the task's scene and the simulated person) started here on
loopback addresses and always stopped; and, without a network, the move to the start pose and the
FR3's gains.

The servers run slowed down (REALTIME) so that a loaded 2-core machine keeps up; lateness is
measured on the robot's clock (RobotState.t), never on the wall clock. Episodes are shortened (a
task duration override, on the client and on the server alike) to keep the suite's time modest.
"""

from __future__ import annotations

import argparse
import dataclasses
import io
import json
import math
import sys
import time
from collections.abc import Iterator
from importlib import resources
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from conftest import load_bench
from fake_arm import FakeArm

import phri
from phri import Robot
from phri.cli import main as cli
from phri.config import load_task
from phri.control import LATE_AFTER, RobotState, safety_limits
from phri.exceptions import ConfigError, ConnectionLostError, PlanningError, SafetyStopError
from phri.franka.episode import FrankaEpisode
from phri.franka.move import MOVE_SPEED, plan_move
from phri.franka.sim_server import SimServer
from phri.sim.episode import VELOCITY_MARGIN, EpisodeConfig, make_learner, replan_settings
from phri.view import read_log, replay_data

pytest.importorskip("pylibfranka", reason="phri[franka] is part of make dev")
pytest.importorskip("franky_sim", reason="phri[franka-sim] is part of make dev")

#: Slow-down of the servers under test: a tick takes this many milliseconds of wall time (at 2, a
#: client on a loaded 2-core machine sometimes missed three ticks in a row: a late-ticks stop).
REALTIME = 3.0
#: The moves to the start pose in these tests: three times the default speed (less waiting).
FAST_MOVE = 3 * MOVE_SPEED
FR3 = Robot.fr3()
LIMITS = safety_limits(FR3, "fr3", load_task("fr3_table"))
FR3_THRESHOLDS = phri.robots.load("fr3").thresholds


def short_table(duration: float) -> phri.config.Task:
    return dataclasses.replace(load_task("fr3_table"), duration=duration)


def check_within_limits(log: dict[str, np.ndarray], prefix: str = "") -> None:
    """Every logged row within the safety layer's limits, checked here from the log itself (joint
    positions, velocities, the applied torque against the URDF's efforts, the tool in its box)."""
    q, qd, tau = (log[f"{prefix}{key}"] for key in ("q", "qd", "tau"))
    assert len(q) > 0
    assert np.all(q >= LIMITS.position_lower) and np.all(q <= LIMITS.position_upper)
    assert np.all(np.abs(qd) <= LIMITS.velocity)
    assert np.all(np.abs(tau) <= FR3.effort_limits + 1e-9)
    assert LIMITS.tool_box is not None
    tool = FR3.frame_pose(LIMITS.tool, q)[:, :3, 3]
    assert np.all(tool >= LIMITS.tool_box[0]) and np.all(tool <= LIMITS.tool_box[1])


# -- the FR3's gains and the move to the start pose (no network) ---------------------------------------


def test_the_fr3_runs_with_its_descriptions_gains_and_the_jaco2_with_the_cores() -> None:
    from phri.robots import impedance_controller, load

    fr3 = impedance_controller(FR3, "fr3")
    np.testing.assert_array_equal(fr3.stiffness, [600, 600, 600, 600, 250, 150, 50])
    np.testing.assert_array_equal(fr3.damping, [50, 50, 50, 50, 30, 25, 15])
    # About critically damped for a unit inertia (2·√k), as libfranka's examples tune them.
    np.testing.assert_allclose(fr3.damping, 2 * np.sqrt(fr3.stiffness), rtol=0.1)
    jaco2 = impedance_controller(Robot.jaco2(), "jaco2")
    default = phri.ImpedanceController(Robot.jaco2())
    np.testing.assert_array_equal(jaco2.stiffness, default.stiffness)
    np.testing.assert_array_equal(jaco2.damping, default.damping)
    assert load("jaco2").stiffness is None
    # The FR3 caps the blend into a new plan at 0.25 of its rated speeds; the JACO2 does not.
    assert load("fr3").transition_speed == 0.25 and load("jaco2").transition_speed is None
    # What builds an episode's controller reads them.
    episode = FrankaEpisode("127.0.18.1", short_table(1.0))
    np.testing.assert_array_equal(episode.controls.controller.stiffness, fr3.stiffness)
    assert episode.controls.thresholds == load("fr3").thresholds


@pytest.mark.parametrize(
    ("table", "message"),
    [
        ("stiffness = [1.0, 2.0]", "key 'impedance.damping' must be given with 'impedance.stiffness'"),
        (
            "stiffness = [1.0]\ndamping = [0.0]",
            "key 'impedance.damping' must be a list of finite numbers > 0",
        ),
        ("stiffness = [1.0]\ndamping = [1.0]", "key 'impedance.stiffness' must have one value per joint .7."),
        ("mass = 1.0", "impedance"),
    ],
)
def test_a_bad_impedance_table_is_a_clear_error(tmp_path: Path, table: str, message: str) -> None:
    from phri.robots import impedance_controller

    source = Path(str(resources.files("phri").joinpath("robots", "fr3")))
    text = (
        (source / "robot.toml")
        .read_text()
        .replace(
            "[impedance]\nstiffness = [600.0, 600.0, 600.0, 600.0, 250.0, 150.0, 50.0]\n"
            "damping = [50.0, 50.0, 50.0, 50.0, 30.0, 25.0, 15.0]",
            f"[impedance]\n{table}",
        )
    )
    assert "[impedance]\n" + table in text
    (tmp_path / "robot.toml").write_text(text.replace('urdf = "fr3.urdf"', f'urdf = "{source / "fr3.urdf"}"'))
    with pytest.raises(ConfigError, match=message):
        impedance_controller(FR3, tmp_path / "robot.toml")


@pytest.mark.parametrize("value", ["0.0", "1.5", '"fast"'])
def test_a_bad_transition_speed_is_a_clear_error(tmp_path: Path, value: str) -> None:
    from phri.robots import load

    source = Path(str(resources.files("phri").joinpath("robots", "fr3")))
    text = (source / "robot.toml").read_text()
    assert "transition_speed = 0.25\n" in text
    text = text.replace("transition_speed = 0.25\n", f"transition_speed = {value}\n")
    (tmp_path / "robot.toml").write_text(text.replace('urdf = "fr3.urdf"', f'urdf = "{source / "fr3.urdf"}"'))
    message = r"key 'interaction.transition_speed' must be a fraction in \(0, 1\]"
    with pytest.raises(ConfigError, match=message):
        load(tmp_path / "robot.toml")


def test_on_the_fr3_the_loop_holds_the_wrist_with_the_gains_of_its_description() -> None:
    """The loop's explicit law (a real arm's) pushes the wrist back with K·e, libfranka's examples'
    stiffness; the implicit law, which divides by phri's model's inertia (no rotors: joint 7's link
    alone, about 0.002 kg·m²), would push with about a tenth of it, which left franky-sim's FR3
    0.045 rad off its start against the joint's friction (0.25 N·m) after the move."""
    from phri.control import ControlLoop
    from phri.franka.move import JointMove
    from phri.robots import impedance_controller

    start = load_task("fr3_table").start
    off = start + np.array([0, 0, 0, 0, 0, 0, 0.044])
    commands = {}
    for implicit in (False, True):
        arm = FakeArm(FR3, off, gravity_compensated=True)  # held still (by friction, say) off its start
        hold = JointMove(start, start, 0.001, settle=0.02)
        controller = impedance_controller(FR3, "fr3")
        loop = ControlLoop(arm, hold, controller, LIMITS, implicit=implicit)  # type: ignore[arg-type]
        result = loop.run(start, hold.total, check=True)
        assert result.stop is None
        commands[implicit] = arm.commands[-1]  # the torque less g(q): the spring's alone
    np.testing.assert_allclose(commands[False][6], -50.0 * 0.044, rtol=1e-6)
    assert abs(commands[True][6]) < 0.2 * 50.0 * 0.044
    with pytest.raises(phri.exceptions.InvalidParameterError, match="implicit must be True or False"):
        ControlLoop(FakeArm(FR3, start, gravity_compensated=True), hold, controller, LIMITS, implicit=1)  # type: ignore[arg-type]
    with pytest.raises(phri.exceptions.InvalidParameterError, match="duration must be a finite time > 0 s"):
        JointMove(start, start, 0.0)


def test_the_learners_seed_plans_and_spin_on_a_real_arm_and_in_simulation(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A real arm's replans race the wall clock: by default the learner plans WALL_CLOCK_SEEDS seed
    plans per learned weight (fewer where that many would pass MAX_SEEDS) for its replans to
    start from; simulated episodes, impedance and unbounded weights plan none; an impedance episode
    never spins; ``phri run --seeds/--worker-spin`` reach the learner."""
    import phri.franka.run as run_module
    import phri.sim.episode as episode_module

    made: list[dict] = []
    monkeypatch.setattr(episode_module, "Learner", lambda *args, **kwargs: made.append(kwargs))
    task = load_task("fr3_table")
    planner = SimpleNamespace(features=None, optimizer=None)
    open_ended = tuple(dataclasses.replace(f, upper=math.inf) if f.learned else f for f in task.features)
    unbounded = dataclasses.replace(task, features=open_ended)
    learned = [f for f in task.features if f.learned]
    assert len(learned) == 1
    three = dataclasses.replace(
        task, features=(*task.features, *(dataclasses.replace(learned[0], name=n) for n in "ab"))
    )
    seven = dataclasses.replace(
        task, features=(*task.features, *(dataclasses.replace(learned[0], name=n) for n in "abcdef"))
    )
    cases = [
        (task, EpisodeConfig(), None, episode_module.WALL_CLOCK_SEEDS),
        (task, EpisodeConfig(), 0.001, 0),
        (task, EpisodeConfig(strategy="impedance"), None, 0),
        (unbounded, EpisodeConfig(), None, 0),
        (task, EpisodeConfig(seeds=3), 0.001, 3),
        (task, EpisodeConfig(seeds=0), None, 0),
        (three, EpisodeConfig(), None, 4),  # 4³ = 64 = MAX_SEEDS
        (seven, EpisodeConfig(), None, 0),  # 2⁷ > 64
    ]
    assert episode_module.MAX_SEEDS == phri.Learner.MAX_SEEDS == 64
    for case_task, config, latency, seeds in cases:
        assert replan_settings(case_task, config, latency) == (seeds, 0.0), (config, latency)
    spinning = EpisodeConfig(worker_spin=math.inf)
    assert replan_settings(task, spinning, None)[1] == math.inf
    assert replan_settings(task, dataclasses.replace(spinning, strategy="impedance"), None) == (0, 0.0)
    make_learner(task, planner, spinning, FR3_THRESHOLDS, replan_latency=None)  # type: ignore[arg-type]
    assert (made[-1]["seeds"], made[-1]["worker_spin"]) == (episode_module.WALL_CLOCK_SEEDS, math.inf)

    configs: list[EpisodeConfig] = []

    def run_episode_at(*args: object, config: EpisodeConfig, **kwargs: object) -> None:
        configs.append(config)
        raise ZeroDivisionError  # stops phri run here, before any connection

    monkeypatch.setattr(run_module, "run_episode_at", run_episode_at)
    parser = argparse.ArgumentParser()
    run_module.add_arguments(parser)
    common = ["--robot", "fr3", "--host", "127.0.0.1", "--task", "fr3_table", "--strategy", "learning"]
    for extra, seeds, spin in [([], None, 0.0), (["--seeds", "2", "--worker-spin", "inf"], 2, math.inf)]:
        with pytest.raises(ZeroDivisionError):
            run_module.run(parser.parse_args(common + extra))
        assert (configs[-1].seeds, configs[-1].worker_spin) == (seeds, spin)


def test_the_move_is_minimum_jerk_and_peaks_at_its_speed() -> None:
    task = load_task("fr3_table")
    move = plan_move(FR3, LIMITS, task.goal, task.start, scene=task.scene)
    out = (np.zeros(7), np.zeros(7), np.zeros(7))
    dt = 1e-3
    t = np.arange(0.0, move.total + dt / 2, dt)
    rows = [[a.copy() for a in move.reference(ti, out=out)] for ti in t]
    q, qd, qdd = (np.array([r[i] for r in rows]) for i in range(3))
    np.testing.assert_allclose(q[0], task.goal)
    np.testing.assert_allclose(q[-1], task.start)
    # At rest at both ends and while it settles; velocity and acceleration are q's derivatives.
    assert np.abs(qd[[0, -1]]).max() < 1e-12 and np.abs(qdd[[0, -1]]).max() < 1e-9
    np.testing.assert_allclose(np.gradient(q, dt, axis=0)[1:-1], qd[1:-1], atol=1e-5)
    np.testing.assert_allclose(np.gradient(qd, dt, axis=0)[1:-1], qdd[1:-1], atol=2e-4)
    # The fastest joint peaks at MOVE_SPEED of its rated velocity, the others slower.
    ratio = np.abs(qd).max(axis=0) / FR3.velocity_limits
    assert ratio.max() == pytest.approx(MOVE_SPEED, rel=1e-4)
    assert move.duration == pytest.approx(15 / 8 * 1.2 / (MOVE_SPEED * 2.62))


def test_a_move_that_is_far_outside_the_limits_or_through_the_table_is_refused() -> None:
    task = load_task("fr3_table")
    far = task.start.copy()
    far[0] += 1.6
    with pytest.raises(PlanningError, match=r"too far from the start pose .* joint 1 is 1.60 rad away"):
        plan_move(FR3, LIMITS, far, task.start, scene=task.scene)
    outside = task.start.copy()
    outside[3] = -0.1  # beyond joint 4's upper limit less the margin
    with pytest.raises(PlanningError, match=r"the arm is outside the safety layer's joint limits .* joint 4"):
        plan_move(FR3, LIMITS, outside, task.start, scene=task.scene)
    # Straight down into the table: the shoulder forward, from above the table to under its top.
    low = task.start.copy()
    low[1] = 1.2
    with pytest.raises(PlanningError, match=r"brings '.*' within -?\d.\d+ m of 'table'|out of its box"):
        plan_move(FR3, LIMITS, task.start, low, scene=task.scene)
    with pytest.raises(phri.exceptions.InvalidParameterError, match="speed must be a fraction"):
        plan_move(FR3, LIMITS, task.goal, task.start, speed=0.9)


# -- episodes over the protocol -----------------------------------------------------------------------


@pytest.fixture(scope="module")
def table_server() -> Iterator[SimServer]:
    """fr3_table shortened to 5 s with the simulated person (seed 0)."""
    with SimServer("127.0.18.2", realtime=REALTIME, task="table", duration=5.0, seed=0) as server:
        yield server


def run_episode(server: SimServer, task: phri.config.Task, strategy: str, **options: object) -> object:
    """One FrankaEpisode on `server`; connects once more after libfranka's own handshake timeout,
    seen under heavy load before anything moved (a lost connection later is a stop, not this)."""
    episode = FrankaEpisode(
        server.host,
        task,
        EpisodeConfig(strategy=strategy),
        move_speed=FAST_MOVE,
        **options,  # type: ignore[arg-type]
    )
    try:
        return episode.run()
    except ConnectionLostError:
        return FrankaEpisode(
            server.host,
            task,
            EpisodeConfig(strategy=strategy),
            move_speed=FAST_MOVE,
            **options,  # type: ignore[arg-type]
        ).run()


def test_learning_needs_less_effort_than_impedance_on_the_fr3(table_server: SimServer) -> None:
    """5 s of the table task over libfranka's protocol with the simulated person: the learner takes
    the correction and is pushed far less; no tick crosses a limit."""
    from phri.sim.episode import run_episode as run_simulated
    from phri.sim.participant import ParticipantParams
    from phri.sim.world import World

    task = short_table(5.0)
    learning = run_episode(table_server, task, "learning")  # the arm starts at the start pose
    impedance = run_episode(table_server, task, "impedance")  # it is at the goal: a move first
    for outcome in (learning, impedance):
        assert outcome.error is None and outcome.stop is None, outcome.error  # type: ignore[attr-defined]
        r = outcome.result  # type: ignore[attr-defined]
        log = r.log_arrays
        # The loop's record: no stop, no torque clipped to a limit; and the log, checked here.
        assert len(log["stop_reason"]) == 0 and not log["torque_clips"].any()
        check_within_limits(log)
        assert log["t"][-1] >= task.duration - 0.02
        # Lateness on the robot's clock: every tick counted, the late ones too.
        assert outcome.ticks + outcome.late_ticks >= 0.9 * task.duration / 1e-3  # type: ignore[attr-defined]
        assert int(log["late_ticks"]) == outcome.late_ticks and float(log["max_tick_gap"]) < 0.1  # type: ignore[attr-defined]
    assert learning.move is None  # type: ignore[attr-defined]
    assert impedance.move is not None and len(impedance.result.log_arrays["move_t"]) > 50  # type: ignore[attr-defined]
    check_within_limits(impedance.result.log_arrays, "move_")  # type: ignore[attr-defined]
    assert len(learning.result.log_arrays["move_t"]) == 0  # type: ignore[attr-defined]
    le, ie = learning.result.effort, impedance.result.effort  # type: ignore[attr-defined]
    assert le < 0.75 * ie, (le, ie)  # the default study's people: 0.33 of it on the JACO2's table
    weights = learning.result.final_weights  # type: ignore[attr-defined]
    # Learned from 0 towards the true weight (1) within the 5 s.
    assert weights[task.task_index] > 0.25 and impedance.result.final_weights[task.task_index] == 0.0  # type: ignore[attr-defined]
    # The same keys as a simulated episode's log (a JACO2 one, 0.5 s), and the FR3's own.
    table = load_task("table")  # its first 0.5 s (the goal moved towards the start in proportion)
    goal = table.start + (table.goal - table.start) * 0.5 / table.duration
    jaco2 = dataclasses.replace(table, duration=0.5, waypoints=7, goal=goal)
    with World() as world:
        simulated = run_simulated(jaco2, world, ParticipantParams()).log_arrays
    assert set(simulated) <= set(learning.result.log_arrays)  # type: ignore[attr-defined]
    extra = set(learning.result.log_arrays) - set(simulated)  # type: ignore[attr-defined]
    assert {"ticks", "late_ticks", "max_tick_gap", "replan_converged"} <= extra
    assert all(
        k.startswith("move_") for k in extra - {"ticks", "late_ticks", "max_tick_gap", "replan_converged"}
    )


# -- faults: injected and survived, the log complete -----------------------------------------------


@pytest.fixture(scope="module")
def faults_server() -> Iterator[SimServer]:
    """fr3_table shortened to 2 s with the simulated person; faults through the control channel."""
    with SimServer("127.0.18.3", realtime=REALTIME, task="table", duration=2.0, seed=0) as server:
        yield server


def inject_at_start(server: SimServer, *faults: str):  # type: ignore[no-untyped-def]
    """A tick hook that injects `faults` (timed into the episode's motion) at its first tick: the
    move to the start, a motion of its own, never sees them."""

    def hook(k: int, state: RobotState, row: int) -> None:
        if k == 0:
            for fault in faults:
                server.inject(fault)

    return hook


@pytest.mark.parametrize(
    ("fault", "message"),
    [
        (
            "reflex:joint_reflex@0.3",
            r"motion aborted by reflex! \[\"joint_reflex\"\].*automatic_error_recovery",
        ),
        ("nan:q@0.3", r"the robot's state has non-finite values \(q\[0\]=nan"),
    ],
    ids=["reflex", "nan"],
)
def test_a_fault_of_the_robot_stops_the_episode_with_a_complete_log(
    faults_server: SimServer, fault: str, message: str, tmp_path: Path
) -> None:
    from phri.franka.run import write_run

    task = short_table(2.0)
    episode = FrankaEpisode(faults_server.host, task, EpisodeConfig(), move_speed=FAST_MOVE)
    outcome = episode.run(on_tick=inject_at_start(faults_server, fault))
    assert isinstance(outcome.error, SafetyStopError)
    stop = outcome.stop
    assert stop is not None and stop.reason == "robot_fault"
    assert __import__("re").search(message, stop.message), stop.message
    assert 0.29 <= stop.t <= 0.31  # on the robot's clock
    # The log is complete up to the stop and records it; written as `phri run` writes it.
    log = outcome.result.log_arrays
    assert log["t"][-1] <= stop.t and log["t"][-1] >= 0.28
    assert list(log["stop_reason"]) == ["robot_fault"] and np.isfinite(log["q"]).all()
    written = write_run(tmp_path, episode, outcome)
    with np.load(written.log) as saved:
        assert str(saved["stop_message"][0]) == stop.message and len(saved["t"]) == len(log["t"])
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["stop"]["reason"] == "robot_fault" and summary["completed"] is False
    # `phri view` opens the FR3's log as it opens a simulated one: the FR3's spheres, the stop.
    replay = replay_data(read_log(written.log))
    assert replay["robot"] == "fr3" and replay["stop"]["reason"] == "robot_fault"
    fr3 = Robot.fr3()
    spheres = sum(len(fr3.collision_spheres(b)[1]) for b in fr3.collision_bodies)
    assert len(replay["spheres"]["radius"]) == spheres == len(replay["frames"]["spheres"][0])
    assert cli(["view", str(written.log), "--html", str(tmp_path / "replay.html")]) == 0
    # The next episode recovers the robot (automatic_error_recovery) and moves it back.
    again = run_episode(faults_server, task, "impedance")
    assert again.error is None and again.move is not None  # type: ignore[attr-defined]


def test_late_ticks_are_survived_and_counted_on_the_robots_clock(faults_server: SimServer) -> None:
    task = short_table(2.0)
    episode = FrankaEpisode(
        faults_server.host, task, EpisodeConfig(strategy="impedance"), move_speed=FAST_MOVE
    )
    outcome = episode.run(on_tick=inject_at_start(faults_server, "late:20@0.5", "late:12@1.0"))
    assert outcome.error is None and outcome.stop is None
    log = outcome.result.log_arrays
    # The injected gaps (20 and 12 ms; this machine's own late ticks may add to them) on the robot's
    # clock, and the episode ran on to its end.
    assert outcome.late_ticks >= 2 and outcome.max_tick_gap >= 0.0195
    assert log["t"][-1] >= task.duration - 0.02
    check_within_limits(log)


def test_a_replan_that_does_not_converge_and_a_stalled_worker_leave_the_tick_alone(
    faults_server: SimServer,
) -> None:
    """The learner's worker: replans stopped after ten Newton iterations, short of tolerances they
    cannot reach, are adopted and said so in the log; a worker stalled for a second of wall time
    holds no tick up. (After five, a sequence of unfinished plans on this 2 s task, blended one into
    the next, ran a joint past its velocity limit and the safety layer stopped the arm.)"""
    task = short_table(2.0)
    config = EpisodeConfig(strategy="learning")
    episode = FrankaEpisode(faults_server.host, task, config, move_speed=FAST_MOVE)
    planner = episode.controls.planner
    hasty = phri.TrajectoryOptimizer(
        planner.features,
        task.waypoints,
        duration=task.duration,
        speed_fraction=VELOCITY_MARGIN,
        max_iterations=10,
        gradient_tolerance=1e-300,  # out of reach: every replan stops short of converging
        relative_tolerance=1e-300,
    )
    episode.learner = make_learner(
        task, planner, config, episode.controls.thresholds, replan_latency=None, optimizer=hasty
    )
    outcome = episode.run()
    assert outcome.error is None and outcome.stop is None
    log = outcome.result.log_arrays
    converged = log["replan_converged"]
    assert (converged == 0).any() and not (converged == 1).any(), converged
    assert len(log["plan_t"]) >= 2  # adopted: feasible, if not optimal
    check_within_limits(log)

    stalled = FrankaEpisode(faults_server.host, task, config, move_speed=FAST_MOVE)
    stalled.learner._debug_stall_worker(1.0)
    ticks: list[float] = []
    outcome = stalled.run(on_tick=lambda k, state, row: ticks.append(state.t))
    assert outcome.error is None and outcome.stop is None
    log = outcome.result.log_arrays
    push, adopted = log["interaction_t"][0], log["plan_t"][1]
    # A second of wall time passed before the plan came; the ticks went on meanwhile.
    during = np.count_nonzero((np.array(ticks) > push) & (np.array(ticks) < adopted))
    assert adopted - push > 0.1 and during > 100
    steps = np.diff(ticks)
    assert np.count_nonzero(steps > LATE_AFTER * 1e-3) == outcome.late_ticks < 0.2 * len(ticks)


def test_the_server_killed_mid_episode_is_a_lost_connection_with_a_complete_log(tmp_path: Path) -> None:
    from phri.franka.run import write_run

    task = short_table(2.0)
    with SimServer("127.0.18.4", realtime=REALTIME, task="table", duration=2.0, seed=0) as server:
        episode = FrankaEpisode(server.host, task, EpisodeConfig(), move_speed=FAST_MOVE)

        def kill(k: int, state: RobotState, row: int) -> None:
            if state.t >= 0.3 and server.process is not None:
                server.stop()

        began = time.monotonic()
        outcome = episode.run(on_tick=kill)
        assert server.process is None
    assert time.monotonic() - began < 60
    assert isinstance(outcome.error, SafetyStopError)
    stop = outcome.stop
    assert stop is not None and stop.reason == "connection_lost" and "stopped answering" in stop.message
    log = outcome.result.log_arrays
    assert 0.29 <= log["t"][-1] <= stop.t + 1e-9 and list(log["stop_reason"]) == ["connection_lost"]
    written = write_run(tmp_path, episode, outcome)
    assert written.log.is_file() and json.loads((tmp_path / "summary.json").read_text())["stop"][
        "reason"
    ] == ("connection_lost")


# -- the live study ------------------------------------------------------------------------------------


def test_the_live_study_is_interrupted_resumed_and_reported(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """1 participant, the table task once per strategy, 3 s episodes, the simulated person standing
    in and the experimenter's answers scripted on stdin: paused at the second episode's go ('q'),
    resumed by the same command, then reported as a simulated study is."""
    import pandas as pd

    from phri.study.cli import main
    from phri.study.results import load_results

    run = tmp_path / "live"
    answers = "".join(f"{1 + i % 7}\n" for i in range(10))
    with SimServer("127.0.18.5", realtime=REALTIME, task="table", duration=3.0, seed=0) as server:
        live = ["--robot", "fr3", "--host", server.host, "--live", "--move-speed", str(FAST_MOVE)]
        design = ["--participants", "1", "--tasks", "table", "--attempts", "1", "--familiarization", "none"]
        # Go, the questionnaire after the first strategy, then 'q' at the next go.
        monkeypatch.setattr(sys, "stdin", io.StringIO("\n" + answers + "q\n"))
        assert main(["study", str(run), *live, *design, "--duration", "3"]) == 0
        out = capsys.readouterr().out
        assert "Episode 1 of 2: participant 1, strategy 'impedance' (1 of 2), task fr3_table" in out
        assert "Questionnaire: participant 1, strategy 'impedance'" in out
        assert "Episode 2 of 2: participant 1, strategy 'learning' (2 of 2)" in out
        assert (
            "paused at the experimenter's request; every finished episode is kept. Resume with: "
            f"phri study {run}" in out
        )
        assert len(load_results(run)) == 1
        # Resumed: the arm moves back to the start, the second episode runs, the questionnaire.
        monkeypatch.setattr(sys, "stdin", io.StringIO("\n" + answers))
        assert main(["study", str(run), *live]) == 0
        out = capsys.readouterr().out
        assert "Episode 1 of 2" not in out and "Episode 2 of 2" in out
        assert "2 of 2 episodes recorded (1 run now with 1 live worker(s)" in out
    table = load_results(run)
    assert list(table["strategy"]) == ["impedance", "learning"] and (table["status"] == "ok").all()
    assert list(table["task"]) == ["fr3_table", "fr3_table"]
    # The person pushed in both (whether learning pays off in so short an episode is the FR3
    # episode test's question, not this one's).
    assert (table["effort"] > 0).all() and (table["interaction_time"] > 0).all()
    answered = pd.read_csv(run / "questionnaire.csv")
    assert list(answered["strategy"]) == ["impedance", "learning"] and list(answered.iloc[0, 2:]) == [
        1,
        2,
        3,
        4,
        5,
        6,
        7,
        1,
        2,
        3,
    ]
    with np.load(run / table["log"][1]) as log:
        assert len(log["move_t"]) > 0 and len(log["stop_reason"]) == 0  # it moved back first
    from phri.cli import main as phri_main

    assert phri_main(["report", str(run)]) == 0
    assert (run / "report" / "report.md").is_file()
    assert "fr3_table" in (run / "report" / "report.md").read_text()


# -- bad input ---------------------------------------------------------------------------------------


def test_an_address_where_nothing_answers_is_a_clear_error_within_the_timeout(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from phri.cli import main

    out = tmp_path / "run"
    began = time.monotonic()
    arguments = ["run", "--robot", "fr3", "--task", "table", "--strategy", "learning", "--out", str(out)]
    assert main([*arguments, "--host", "127.0.18.6", "--connect-timeout", "1"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("phri run: error: host '127.0.18.6': no robot answers on port 1337 within 1 s")
    assert time.monotonic() - began < 30
    # A bad option is refused before anything connects.
    assert main([*arguments, "--host", "127.0.18.6", "--move-speed", "2"]) == 2
    assert (
        "speed must be a fraction of the rated joint velocities in (0, 0.5], got 2.0"
        in capsys.readouterr().err
    )
    assert not out.exists(), "nothing is written when nothing ran"


def test_a_task_for_another_robot_is_refused_before_anything_connects(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from phri.cli import main

    jaco2_table = str(resources.files("phri").joinpath("tasks", "table.toml"))
    arguments = ["--robot", "fr3", "--host", "127.0.18.8", "--task", jaco2_table, "--strategy", "learning"]
    assert main(["run", *arguments, "--out", str(tmp_path / "run")]) == 2
    assert "posed for robot 'jaco2'" in capsys.readouterr().err
    with pytest.raises(ConfigError, match="posed for robot 'jaco2', not 'fr3'"):
        FrankaEpisode("127.0.18.8", load_task("table"))
    live = ["study", str(tmp_path / "study"), "--robot", "fr3", "--host", "127.0.18.8", "--live"]
    assert main([*live, "--tasks", jaco2_table, "--participants", "1"]) == 2
    assert "posed for robot 'jaco2', not 'fr3'" in capsys.readouterr().err
    assert not (tmp_path / "study").exists()
    assert main(["study", str(tmp_path / "study"), "--live", "--participants", "1"]) == 2
    assert "--live needs --robot fr3 and --host" in capsys.readouterr().err
    assert main(["study", str(tmp_path / "study"), "--robot", "fr3", "--participants", "1"]) == 2
    assert "--robot only go with --live" in capsys.readouterr().err


def test_the_live_runner_records_a_stopped_episode_or_runs_it_again_at_the_experimenters_word(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The prompts after a stop and after an episode that never started, with stand-in episodes
    (no arm): 'r' runs a stopped episode again and keeps its log beside; Enter records a stopped
    one as failed; an episode that did not start is tried again, never recorded; 'q' pauses."""
    from phri.control import StopEvent
    from phri.franka.episode import FrankaOutcome
    from phri.sim.episode import EpisodeResult
    from phri.study import live
    from phri.study.protocol import StudyConfig, schedule

    config = StudyConfig(participants=1, tasks=("fr3_table",), familiarization=None, attempts=1, duration=1.0)
    spec = schedule(config)[0]
    nan7 = np.full(7, np.nan)
    stop = StopEvent("robot_fault", "the robot reports robot mode Reflex", 5, 0.005, nan7, nan7, nan7, nan7)

    def result(stopped: bool) -> EpisodeResult:
        arrays = {"t": np.zeros(1), **(stop.arrays() if stopped else StopEvent.empty_arrays(7))}
        return EpisodeResult(
            "fr3_table", spec.strategy, 1.0, 0.1, 2.0, 2.0, np.zeros(2), np.ones(2), 1, 0.0, 0.1, 0.0, 0.0,
            0.0, log_arrays=arrays, stop=stop if stopped else None,
        )  # fmt: skip

    def stopped() -> FrankaOutcome:
        r = result(True)
        return FrankaOutcome(r, SafetyStopError(str(stop), stop), log_arrays=r.log_arrays)

    script = [
        FrankaOutcome(None, ConnectionLostError("host: the robot stopped answering")),  # not started
        stopped(),  # stopped: run it again
        stopped(),  # stopped: record it as failed
    ]
    ran: list[FrankaOutcome] = []

    class Stand:
        def __init__(self, *args: object, **options: object) -> None:
            pass

        def run(self) -> FrankaOutcome:
            ran.append(script[len(ran)])
            return ran[-1]

    monkeypatch.setattr(live, "FrankaEpisode", Stand)
    answers = iter(["", "", "r", ""])  # go; try again; run it again; record it as failed
    told: list[str] = []
    runner = live.LiveRunner(
        config, config.load_tasks(), 2, host="127.0.18.9", run_dir=tmp_path,
        read=lambda prompt: next(answers), write=told.append,
    )  # fmt: skip
    (tmp_path / "logs").mkdir()
    outcome = runner.episode(spec)
    assert len(ran) == 3
    assert any("did not start: host: the robot stopped answering" in line for line in told)
    assert outcome.row["status"] == "failed" and "robot mode Reflex" in str(outcome.row["error"])
    stem = spec.log_name(2).removesuffix(".npz")
    with np.load(tmp_path / "logs" / f"{stem}.stopped-1.npz") as kept:
        assert str(kept["stop_reason"][0]) == "robot_fault"
    # 'q' at the go, or the terminal's input ending, pauses.
    runner.read = lambda prompt: "q"
    with pytest.raises(live.StudyPaused, match="experimenter's request"):
        runner.episode(spec)

    def ended(prompt: str) -> str:
        raise EOFError

    runner.read = ended
    with pytest.raises(live.StudyPaused, match="input ended"):
        runner.episode(spec)


def test_the_push_to_adoption_bench_runs_and_times_every_task(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """benches/push_adoption.py (make bench-push) on one sequence: every FR3 task replans after a
    push in each of the three settings and gets a row of finite times, so the bench does not rot."""
    bench = load_bench("push_adoption")
    monkeypatch.setattr(sys, "argv", ["push_adoption.py", "--sequences", "1"])
    bench.main()
    out = capsys.readouterr().out
    rows = [line.split() for line in out.splitlines() if line.strip().startswith("fr3_")]
    assert [r[0] for r in rows] == list(bench.TASKS) * 3, out
    for row in rows:
        pushes, times = int(row[1]), [float(v) for v in row[2:5] + [row[5], row[7]]]
        assert pushes >= 1 and all(math.isfinite(v) and 0 < v < 10_000 for v in times), row
