"""The simulated study in PyBullet (DIRECT mode): tracking, compliance, the participant, episodes,
and the paper's result — learning beats impedance on every task — with a fixed seed."""

from __future__ import annotations

import io
import subprocess
import sys

import numpy as np
import pytest

import phri
from phri.config import knots_fit
from phri.exceptions import InvalidParameterError, PlanningError, SafetyStopError, SimulationError
from phri.sim import (
    LATER_THRESHOLDS,
    ORIGINAL_THRESHOLDS,
    EpisodeConfig,
    ParticipantParams,
    Planner,
    World,
    WorldParams,
    run_episode,
)
from phri.sim.episode import encode_log, make_learner, simulate_episode
from phri.sim.participant import default_population
from phri.sim.world import HAND

NOBODY = ParticipantParams(tolerance=1e9, tilt_tolerance=1e9)


def shortened(task: phri.Task, duration: float, waypoints: int) -> phri.Task:
    """`task` cut to its first `duration` seconds: the goal moved towards the start in proportion,
    so the plan moves as fast as the full task's; planned by the task's knots where they fit on
    `waypoints` (7 or 13 for the study's 4), else on every waypoint."""
    goal = task.start + (task.goal - task.start) * duration / task.duration
    knots = task.knots if knots_fit(task.knots, waypoints) else 0
    return phri.Task(
        **{**task.__dict__, "duration": duration, "waypoints": waypoints, "goal": goal, "knots": knots}
    )


@pytest.mark.slow
@pytest.mark.parametrize("name", ["human", "coffee", "table", "laptop"])
def test_the_arm_tracks_its_plan_within_2_cm_with_nobody_touching_it(world, planners, name) -> None:
    task = phri.load_task(name)
    r = run_episode(task, world, NOBODY, EpisodeConfig(strategy="impedance"), planner=planners[name])
    assert r.effort == 0.0 and r.interaction_time == 0.0
    assert r.tracking_error < 0.02, f"{name}: the hand strayed {r.tracking_error:.3f} m from its reference"
    np.testing.assert_allclose(r.final_weights, r.initial_weights)


def test_a_20_N_push_at_the_hand_visibly_deflects_it(world) -> None:
    task = phri.load_task("table")
    world.reset(task.start)
    controller = phri.ImpedanceController(world.model)
    tau = np.zeros(7)
    for _ in range(1500):
        q, qd = world.state()
        controller.torque_implicit(q, qd, task.start, np.zeros(7), 1e-3, out=tau)
        world.step(tau, np.array([0.0, 0.0, -20.0]))
    q, _ = world.state()
    moved = world.model.frame_pose(HAND, task.start)[:3, 3] - world.model.frame_pose(HAND, q)[:3, 3]
    # As compliant as the study's arm (admittance mode): a push moves the cup tens of centimetres.
    assert moved[2] > 0.1, f"a 20 N downward push moved the hand only {moved} m"
    assert np.linalg.norm(moved) < 0.6


def test_the_simulator_agrees_with_phri_on_gravity_with_the_cup(world) -> None:
    """Holding still under phri's gravity compensation (arm + cup payload) the arm does not drift."""
    task = phri.load_task("coffee")
    world.reset(task.start)
    for _ in range(500):
        q, _ = world.state()
        world.step(world.model.gravity(q))
    q, qd = world.state()
    assert np.abs(q - task.start).max() < 1e-3
    assert np.abs(qd).max() < 1e-2


@pytest.mark.slow
def test_learning_takes_less_effort_and_time_and_ends_closer_to_the_desired_cost(world, planners) -> None:
    """On average over two people of the default population (people differ: not every one of them
    gains on every task, as in the study)."""
    people = [default_population().draw(0, p) for p in (1, 2)]
    for name, planner in planners.items():
        task = phri.load_task(name)
        runs = {
            s: [
                run_episode(task, world, person, EpisodeConfig(strategy=s), seed=3, planner=planner)
                for person in people
            ]
            for s in ("impedance", "learning")
        }
        imp, learn = runs["impedance"], runs["learning"]
        assert sum(r.effort for r in learn) < sum(r.effort for r in imp), name
        assert sum(r.interaction_time for r in learn) < sum(r.interaction_time for r in imp), name
        gap_learn = sum(abs(r.cost - r.desired_cost) for r in learn)
        gap_imp = sum(abs(r.cost - r.desired_cost) for r in imp)
        assert gap_learn < gap_imp, f"{name}: learning {gap_learn:.3f} vs impedance {gap_imp:.3f}"
        for r in learn:
            assert r.final_weights[task.task_index] > task.vector("initial")[task.task_index], name
        for r in imp:
            np.testing.assert_array_equal(r.final_weights, r.initial_weights)


@pytest.mark.slow
def test_after_a_replan_the_arm_keeps_within_its_velocity_limits(world, planners, tmp_path) -> None:
    """The reference blends into each new plan (TimedTrajectory.switch_to), so the arm does not snap
    onto it; with the original's instant switch its reference jumps, at well over the limits. (A
    person who teaches the robot something: with the match to the demonstration kept within 1 s of
    the clock, rng 7's person pushed the instant-switch robot once on the human task and left its
    weight at 5e-4, so its replans hardly moved the plan.)"""
    person = ParticipantParams.draw(np.random.default_rng(8))
    limits = world.model.velocity_limits
    for name in ("human", "table", "laptop"):
        task = phri.load_task(name)
        speeds, references = {}, {}
        for speed in (0.8, 0.0):
            log = tmp_path / f"{name}-{speed}.npz"
            config = EpisodeConfig(strategy="learning", transition_speed=speed)
            try:
                r = run_episode(task, world, person, config, seed=3, planner=planners[name], log_path=log)
            except SafetyStopError as e:
                # The snap may run the arm past the safety layer's velocity limit (twice the rated
                # speed), which then stops it: the snap, measured by the stop.
                assert speed == 0.0 and e.event.reason == "joint_velocity", (name, speed, e)
                speeds[speed] = abs(e.event.value) / limits[e.event.index]
                continue
            assert r.final_weights[task.task_index] > 0, name
            with np.load(log) as data:
                t, q_ref, pushed = data["t"], data["q_ref"], np.any(data["push"] != 0, axis=1)
                reference = np.abs(np.diff(q_ref, axis=0) / np.diff(t)[:, None]) / limits
                # While the person pushes, they move the arm as fast as they like, and it takes the
                # arm a moment after they let go to slow down; otherwise it follows its reference.
                released = t[1:][pushed[:-1] & ~pushed[1:]]
                free = ~pushed & ~np.any((t[:, None] >= released) & (t[:, None] < released + 0.3), axis=1)
                speeds[speed] = float((np.abs(data["qd"][free]) / limits).max())
                references[speed] = float(reference.max())
            if speed:
                assert reference.max() <= speed + 0.02, (
                    f"{name}: reference at {reference.max():.2f}× the limits"
                )
        assert speeds[0.8] <= 1.0, f"{name}: the arm reached {speeds[0.8]:.2f}× its velocity limits"
        # The instant switch jumps its reference (the person, pushing then, may hold the arm back), or
        # the arm's snap onto it was stopped by the safety layer (measured by the stop).
        jump = references.get(0.0, speeds[0.0])
        assert jump > 1.2, f"{name}: the instant switch no longer jumps ({jump:.2f}×)"


def test_episodes_are_deterministic_and_logs_are_never_overwritten(world, planners, tmp_path) -> None:
    task = phri.load_task("laptop")
    short = shortened(task, 3.0, 7)
    planner = Planner(short, world)
    person = ParticipantParams(tolerance=0.01, delay=0.05)
    a = run_episode(short, world, person, seed=5, planner=planner, log_path=tmp_path / "a.npz")
    b = run_episode(short, world, person, seed=5, planner=planner)
    assert (a.effort, a.cost, a.interaction_time) == (b.effort, b.cost, b.interaction_time)
    with np.load(a.log) as log:
        for key in (
            "t",
            "q",
            "qd",
            "q_ref",
            "tau",
            "u_h",
            "push",
            "weights",
            "weights_t",
            "interaction_delta_phi",
            "plans",
            "plan_t",
            "desired",
        ):
            assert key in log.files
        assert log["q"].shape == (301, 7) and log["plans"].shape[1:] == (7, 7)
    with pytest.raises(FileExistsError):
        run_episode(short, world, person, seed=5, planner=planner, log_path=tmp_path / "a.npz")


def test_replans_on_the_worker_with_a_one_tick_latency_give_the_inline_episode(world) -> None:
    """Issue 14: the simulated study replans on the learner's worker thread with a fixed simulated
    latency; at one tick it reproduces replanning within the tick exactly, and a longer latency
    adopts each plan that much later, never by the wall clock."""
    short = shortened(phri.load_task("table"), 6.0, 13)  # long enough for this person to teach it
    planner = Planner(short, world)
    person = ParticipantParams(tolerance=0.01, delay=0.05)

    def run(latency: float) -> dict[str, np.ndarray]:
        config = EpisodeConfig(replan_latency=latency)
        return run_episode(short, world, person, config, seed=5, planner=planner).log_arrays

    inline, worker, late = run(0.0), run(0.001), run(0.05)
    assert len(inline["plan_t"]) > 1, "the person never made the robot replan: nothing is compared"
    for key in inline:
        np.testing.assert_array_equal(inline[key], worker[key], err_msg=key)
    # The same first push; its plan takes effect 49 ticks later than at one tick.
    assert late["interaction_t"][0] == inline["interaction_t"][0]
    assert late["plan_t"][1] == pytest.approx(inline["plan_t"][1] + 0.049, abs=1e-9)


def test_the_log_in_memory_is_the_log_written(world, tmp_path) -> None:
    short = shortened(phri.load_task("coffee"), 1.0, 5)
    planner = Planner(short, world)
    person = ParticipantParams(tolerance=0.01, delay=0.05)
    written = run_episode(short, world, person, seed=2, planner=planner, log_path=tmp_path / "a.npz")
    result, error = simulate_episode(short, world, person, seed=2, planner=planner)
    assert error is None and result.log is None and not list(tmp_path.glob("*.partial"))
    with np.load(tmp_path / "a.npz") as log, np.load(io.BytesIO(encode_log(result.log_arrays))) as memory:
        assert log.files == memory.files == list(written.log_arrays)
        for key in log.files:
            np.testing.assert_array_equal(log[key], memory[key])
            np.testing.assert_array_equal(log[key], written.log_arrays[key])


def test_a_simulator_failure_is_an_error_and_the_log_so_far_stays_readable(
    world, tmp_path, monkeypatch
) -> None:
    """PyBullet failing (the reference simulator, where the world's state is read every tick; the
    native loop's failures: tests/test_native.py)."""
    task = phri.load_task("table")
    short = shortened(task, 1.0, 5)
    planner = Planner(short, world)
    on_pybullet = EpisodeConfig(simulator="pybullet")
    real_state, calls = world.state, {"n": 0}

    def failing_state():
        calls["n"] += 1
        if calls["n"] > 300:
            raise SimulationError("the simulator returned a non-finite joint state")
        return real_state()

    monkeypatch.setattr(world, "state", failing_state)
    with pytest.raises(SimulationError, match="non-finite"):
        run_episode(short, world, NOBODY, on_pybullet, planner=planner, log_path=tmp_path / "partial.npz")
    with np.load(tmp_path / "partial.npz") as log:
        assert 25 <= len(log["t"]) <= 31
    # Any other failure (a lost simulator, Ctrl-C) also keeps the log, and is re-raised as it was.
    for error in (RuntimeError("the physics server disconnected"), KeyboardInterrupt()):
        calls["n"] = 0

        def interrupted_state(error=error):
            calls["n"] += 1
            if calls["n"] > 500:
                raise error
            return real_state()

        monkeypatch.setattr(world, "state", interrupted_state)
        path = tmp_path / f"{type(error).__name__}.npz"
        with pytest.raises(type(error)):
            run_episode(short, world, NOBODY, on_pybullet, planner=planner, log_path=path)
        with np.load(path) as log:
            assert 45 <= len(log["t"]) <= 51


def test_bad_task_input_is_a_clear_error(world, tmp_path) -> None:
    task = phri.load_task("table")
    outside = phri.Task(**{**task.__dict__, "goal": np.zeros(7)})  # q = 0 violates joints 2, 4, 6
    with pytest.raises(InvalidParameterError, match="outside the limits"):
        Planner(outside, world)
    # A goal too far for the duration at the allowed joint speeds (7 waypoints: the task's 4 knots fit).
    hurried = phri.Task(**{**task.__dict__, "duration": 2.0, "waypoints": 7})
    with pytest.raises(PlanningError, match=r"the goal is too far from the start for duration = 2 s"):
        Planner(hurried, world)
    far = task.goal.copy()
    far[0] += 6.0  # joint 1 is continuous: a goal almost a turn away
    with pytest.raises(PlanningError, match=r"moves a joint .* make the task last longer"):
        Planner(phri.Task(**{**task.__dict__, "goal": far}), world)
    # A table top the arm cannot stay clear of (the goal pose lies in it): the pair is named.
    table = phri.SceneObject("table", "box", [-0.405, 0.0, 0.0], size=[0.81, 1.62, 0.8])
    high = phri.Task(**{**task.__dict__, "scene": phri.Scene([table])})
    with pytest.raises(
        PlanningError, match=r"cannot keep the arm clear: '[a-z0-9_]+' comes within .* of 'table'"
    ):
        Planner(high, world)
    with pytest.raises(InvalidParameterError, match="strategy"):
        EpisodeConfig(strategy="ignore")
    with pytest.raises(InvalidParameterError, match="sample_rate"):
        EpisodeConfig(sample_rate=0)


def test_an_episode_places_the_objects_where_its_task_file_says(world) -> None:
    task = phri.load_task("laptop")
    table, laptop, person = task.scene.objects
    laptop = phri.SceneObject("laptop", "box", [-0.6, 0.3, -0.0891], size=laptop.size)
    person = phri.SceneObject(
        "person", "cylinder", [0.1, 0.4, 0.7484], radius=0.15, length=1.7, kind="person"
    )
    moved = phri.Scene([table, laptop, person])
    short = phri.Task(**{**shortened(task, 1.0, 5).__dict__, "scene": moved})
    run_episode(short, world, NOBODY, EpisodeConfig(strategy="impedance"))
    p, c = world.p, world.client
    at = {
        name: p.getBasePositionAndOrientation(body, physicsClientId=c)[0]
        for name, body in world.bodies.items()
    }
    np.testing.assert_allclose(at["laptop"], (-0.6, 0.3, -0.0891))
    np.testing.assert_allclose(at["person"], (0.1, 0.4, 0.7484))
    np.testing.assert_allclose(at["table"], (-0.405, 0.0, -0.4516))
    assert world.mount_id is not None
    run_episode(shortened(task, 1.0, 5), world, NOBODY, EpisodeConfig(strategy="impedance"))
    laptop_at, _ = p.getBasePositionAndOrientation(world.bodies["laptop"], physicsClientId=c)
    np.testing.assert_allclose(laptop_at[:2], (-0.7929, 0.0))


def test_a_task_without_a_scene_plans_clear_of_nothing_but_itself(world) -> None:
    task = phri.load_task("coffee")
    free = phri.Task(**{**task.__dict__, "scene": phri.Scene()})
    planner = Planner(free, world)
    assert planner.optimizer.collisions
    assert all(
        other.startswith("j2s7s300") or other == "cup" for _, other in planner.optimizer.excluded_pairs
    )


@pytest.mark.parametrize(
    ("make", "pattern"),
    [
        (lambda: ParticipantParams(rate=0.0), r"rate must be a finite number > 0 \[Hz\]"),
        (lambda: ParticipantParams(noise=-1.0), r"noise must be a finite number >= 0 \[N\]"),
        (lambda: ParticipantParams(max_force=float("nan")), r"max_force must be a finite number >= 0 \[N\]"),
        (lambda: ParticipantParams(release=1.5), "release must be a number >= 0 and <= 1"),
        (lambda: EpisodeConfig(sensor_noise=float("inf")), "sensor_noise must be a finite value"),
        (lambda: EpisodeConfig(rule="MAX"), "rule must be one of"),
        (lambda: EpisodeConfig(replan_latency=-0.001), r"replan_latency must be a time in \[0, 1\] s"),
        (lambda: EpisodeConfig(replan_latency=float("nan")), "replan_latency must be a time in"),
        (lambda: WorldParams(timestep=0.0), r"timestep must be a number in \[1e-05, 0.01\] s, got 0.0"),
        (lambda: WorldParams(timestep=float("nan")), "timestep must be a number in"),
        (lambda: WorldParams(gravity=1e300), "gravity must be a number in"),
        (lambda: WorldParams(joint_damping=-1.0), "joint_damping must be a number in"),
    ],
)
def test_bad_participant_and_episode_settings_are_clear_errors(make, pattern) -> None:
    with pytest.raises(InvalidParameterError, match="^" + pattern):
        make()


def test_frame_times_must_be_times_of_the_task(world) -> None:
    """Issue 16 #11: run_episode(frame_times=[nan]) is an error naming the argument."""
    task = shortened(phri.load_task("table"), 1.0, 5)
    for bad in (float("nan"), -1.0, 2.0, "1"):
        with pytest.raises(InvalidParameterError, match=r"^frame_times\[0\] must be a time in \[0, 1\] s"):
            run_episode(task, world, ParticipantParams(), frame_times=[bad])


def test_the_result_row_reports_the_task_features_weight(world) -> None:
    table = shortened(phri.load_task("table"), 1.0, 5)
    task = phri.Task(**{**table.__dict__, "features": table.features[::-1]})  # the task feature first
    assert task.task_index == 0
    r = run_episode(task, world, NOBODY, EpisodeConfig(strategy="impedance"))
    assert r.task_index == 0
    assert r.row()["final_weight"] == r.final_weights[0] == task.vector("initial")[0]


def test_the_person_draws_the_same_noise_whatever_the_sensor_draws(world, tmp_path) -> None:
    """The participant and the sensor have their own random streams: under impedance (which only
    records what it measures) a sensor that draws less often (no noise, a lower sample rate) or more
    often leaves the person's pushes, noise included, unchanged for the same seed."""
    short = shortened(phri.load_task("table"), 3.0, 7)
    planner = Planner(short, world)
    person = ParticipantParams(tolerance=0.005, delay=0.05, noise=3.0)
    pushes, measured = [], []
    for noise, rate in ((0.5, 10.0), (0.0, 10.0), (0.5, 100.0)):
        path = tmp_path / f"sensor-{noise}-{rate}.npz"
        config = EpisodeConfig(strategy="impedance", sensor_noise=noise, sample_rate=rate)
        run_episode(short, world, person, config, seed=5, planner=planner, log_path=path)
        with np.load(path) as log:
            pushes.append(log["push"])
            measured.append(log["u_h"])
    assert np.count_nonzero(np.any(pushes[0] != 0, axis=1)) > 10, "the person never pushed"
    for other in pushes[1:]:
        np.testing.assert_array_equal(pushes[0], other)
    assert not np.array_equal(measured[0], measured[1]) and not np.array_equal(measured[0], measured[2])


def test_the_detectors_thresholds_and_bias_are_configurable(world) -> None:
    short = shortened(phri.load_task("table"), 1.0, 5)
    planner = Planner(short, world)

    def interaction_time(**kwargs) -> float:
        config = EpisodeConfig(strategy="impedance", sensor_noise=0.0, **kwargs)
        return run_episode(short, world, NOBODY, config, planner=planner).interaction_time

    six = (6.0, 0, 0, 0, 0, 0, 0)  # below the original threshold of joint 1 (8), above the later (4)
    assert interaction_time(sensor_bias=six) == 0.0
    assert interaction_time(sensor_bias=six, thresholds=ORIGINAL_THRESHOLDS) == 0.0
    assert interaction_time(sensor_bias=six, thresholds=LATER_THRESHOLDS) == pytest.approx(1.1)  # 11 samples
    ten = (10.0, 0, 0, 0, 0, 0, 0)
    assert interaction_time(sensor_bias=ten) == pytest.approx(1.1)
    assert interaction_time(sensor_bias=ten, detector_bias=ten) == 0.0  # a calibrated sensor
    assert EpisodeConfig(thresholds=np.array(LATER_THRESHOLDS)).thresholds == LATER_THRESHOLDS


def test_the_deformation_gain_reaches_the_learner(world) -> None:
    """EpisodeConfig.deformation_gain is the learner's μ: the same push at a tenth of the default
    gain changes the features a tenth as much (to first order; the table feature is near linear
    over so small a deformation), and the default is phri.Deformation's."""
    task = phri.load_task("table")
    planner = Planner(task, world)
    push = np.array([20.0, 20.0, 20.0, 5.0, 3.0, 3.0, 3.0])  # above every study threshold

    def delta_phi(gain: float | None) -> np.ndarray:
        config = EpisodeConfig(deformation_gain=gain)
        learner = make_learner(task, planner, config, ORIGINAL_THRESHOLDS, replan_latency=0.0)
        learner.observe(1.0, push)
        (change,) = learner.history().delta_phi
        return change

    default = delta_phi(None)
    np.testing.assert_array_equal(default, delta_phi(phri.Deformation().mu))
    k = task.task_index
    assert abs(default[k]) > 1e-3
    assert delta_phi(0.1 * phri.Deformation().mu)[k] == pytest.approx(0.1 * default[k], rel=0.05)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"sensor_bias": (0.5,)}, r"sensor_bias must have one value per joint \(7\) \[N·m\], got 1"),
        ({"sensor_bias": (0.0,) * 8}, r"sensor_bias must have one value per joint"),
        ({"sensor_bias": (0.0,) * 6 + (float("nan"),)}, r"sensor_bias\[6\] must be finite"),
        ({"sensor_bias": "biased"}, r"sensor_bias must be 7 numbers"),
        ({"thresholds": (8.0, 8.0)}, r"thresholds must have one value per joint \(7\)"),
        ({"thresholds": (8, 8, 8, 0, 1, 1, 1)}, r"thresholds\[3\] must be finite and > 0 \[N·m\], got 0"),
        ({"thresholds": (8, 8, 8, 2, 1, 1, -1)}, r"thresholds\[6\] must be finite and > 0"),
        ({"thresholds": (8, 8, 8, 2, 1, 1, float("inf"))}, r"thresholds\[6\] must be finite"),
        ({"detector_bias": (1.0,) * 3}, r"detector_bias must have one value per joint"),
        ({"detector_bias": (float("nan"),) * 7}, r"detector_bias\[0\] must be finite"),
    ],
)
def test_bad_per_joint_settings_are_a_clear_error(kwargs, match) -> None:
    with pytest.raises(InvalidParameterError, match=match):
        EpisodeConfig(**kwargs)


@pytest.mark.parametrize("gain", [0.0, -0.01, float("nan"), float("inf"), True, "0.01"])
def test_a_bad_deformation_gain_is_a_clear_error(gain) -> None:
    with pytest.raises(
        InvalidParameterError, match=r"^deformation_gain must be None or a finite gain > 0 rad per N·m, got "
    ):
        EpisodeConfig(deformation_gain=gain)


def test_rates_must_be_a_whole_number_of_simulator_steps(world) -> None:
    with pytest.raises(
        InvalidParameterError, match=r"sample_rate = 300 Hz .* nearby valid rates: 333.333 Hz, 250 Hz"
    ):
        EpisodeConfig(sample_rate=300)
    with pytest.raises(
        InvalidParameterError, match=r"log_rate = 300 Hz .* nearby valid rates: 333.333 Hz, 250 Hz"
    ):
        EpisodeConfig(log_rate=300)
    with pytest.raises(
        InvalidParameterError, match=r"0.3 Hz .* period is 3333.33 steps.* rates: 0.30003 Hz, 0.29994 Hz"
    ):
        EpisodeConfig(sample_rate=0.3)
    for rate in (0.5, 10, 250, 1000 / 3, 1000):
        EpisodeConfig(sample_rate=rate, log_rate=rate)
    # Against the world's own rate: 1000 Hz is no whole number of 2 ms steps.
    short = shortened(phri.load_task("table"), 1.0, 5)
    with World(params=WorldParams(timestep=2e-3)) as slow:
        with pytest.raises(
            InvalidParameterError, match=r"sample_rate = 1000 Hz .* nearby valid rates: 500 Hz"
        ):
            run_episode(short, slow, NOBODY, EpisodeConfig(sample_rate=1000))
        with pytest.raises(InvalidParameterError, match=r"log_rate = 1000 Hz .* nearby valid rates: 500 Hz"):
            run_episode(short, slow, NOBODY, EpisodeConfig(log_rate=1000))
    # The interaction time counts samples at the rate they were taken at.
    config = EpisodeConfig(
        strategy="impedance", sample_rate=250, sensor_noise=0.0, sensor_bias=(10.0,) + (0,) * 6
    )
    r = run_episode(short, world, NOBODY, config)
    assert r.interaction_time == pytest.approx(251 / 250)


def test_pybullet_prints_nothing_into_the_output() -> None:
    code = "import phri.sim.world as w; print('a'); W = w.World(); print('b'); W.close()"
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=True
    )
    assert done.stdout == "a\nb\n"
    assert "pybullet build time" not in done.stderr
