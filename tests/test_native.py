"""The native episode loop (phri.sim.native: phri.SimulatedLoop on phri.SimulatedArm) against the
Python control loop over PyBullet, the reference: the same episodes on every study task and
strategy, the same stop and hold, the same frames; and its own errors."""

from __future__ import annotations

import dataclasses
import logging

import numpy as np
import pytest

import phri
import phri.demo
import phri.sim.episode
from phri.exceptions import InvalidParameterError, ShapeError, SimulationError
from phri.sim import SIMULATORS, EpisodeConfig, ParticipantParams, run_episode
from phri.sim.backend import PyBulletBackend
from phri.sim.episode import robot_controls, run_on_loop, simulate_episode
from phri.sim.native import run_native
from phri.sim.participant import Participant
from phri.sim.world import HAND
from phri.study.cli import _add_study

#: How far apart the two simulators may be: joint positions [rad] at every log row, and each result
#: relative to itself (docs/simulation.md measures 3e-13 rad and about 1e-13).
ATOL_Q = 1e-9
RTOL = 1e-9
#: Results an episode is scored by.
SCORES = ("effort", "interaction_time", "cost", "tracking_error", "min_clearance", "wall_contact_time")


def both(task, world, person, config, **kwargs):
    """The episode on each simulator: {simulator: (result, error)}."""
    return {
        s: simulate_episode(task, world, person, dataclasses.replace(config, simulator=s), **kwargs)
        for s in SIMULATORS
    }


def assert_same(native, reference) -> None:
    a, b = native.log_arrays, reference.log_arrays
    assert a.keys() == b.keys()
    np.testing.assert_allclose(a["q"], b["q"], rtol=0, atol=ATOL_Q)
    for key in a:
        if a[key].dtype.kind == "f":
            np.testing.assert_allclose(a[key], b[key], rtol=RTOL, atol=1e-9, err_msg=key)
        else:
            np.testing.assert_array_equal(a[key], b[key], err_msg=key)
    for key in SCORES:
        assert getattr(native, key) == pytest.approx(getattr(reference, key), rel=RTOL, abs=1e-12), key
    np.testing.assert_allclose(native.final_weights, reference.final_weights, rtol=RTOL)


@pytest.mark.parametrize("strategy", ["impedance", "learning"])
@pytest.mark.parametrize("name", ["human", "coffee", "table", "laptop"])
def test_a_study_episode_is_the_same_on_both_simulators(world, planners, name, strategy) -> None:
    """Issue 32: the native loop gives the Python loop's episode over PyBullet, with a person who
    pushes and the sensor's noise, for the whole task."""
    task = phri.load_task(name)
    person = ParticipantParams.draw(np.random.default_rng(7))
    # Seed 4: this person pushes on every task and moves the learner's weights (with seed 3, since
    # the off-axis push scales with the push applied, they barely touch the human task's arm).
    runs = both(task, world, person, EpisodeConfig(strategy=strategy), seed=4, planner=planners[name])
    (native, error), (reference, reference_error) = runs["native"], runs["pybullet"]
    assert error is None and reference_error is None
    # Not vacuous: the person pushed, the robot felt it, and (learning) its weights moved.
    assert np.abs(native.log_arrays["push"]).max() > 1.0 and native.interaction_time > 0
    if strategy == "learning":
        assert not np.allclose(native.final_weights, native.initial_weights)
    assert_same(native, reference)


def test_a_safety_stop_and_its_hold_are_the_same_on_both_simulators(world, planners) -> None:
    """A person's push drives a joint past a tightened velocity limit: both loops stop at the same
    tick for the same reason, hold the position for the hold time and log the same."""
    task = phri.load_task("table")
    config = EpisodeConfig(strategy="impedance", sensor_noise=0.0)
    person = ParticipantParams()  # their push turns joint 7 at up to 0.6 rad/s; the plan, 0.17 at most
    traces = {}
    for simulator in SIMULATORS:
        controls = robot_controls(task, world.model, config, planners["table"], replan_latency=0.001)
        limits = dataclasses.replace(controls.limits, velocity=np.full(7, 0.3))
        rng = np.random.default_rng(1)
        pusher = Participant(person, task, world.model, planners["table"].desired, rng)
        if simulator == "native":
            run = run_native(
                world, task.start, task.duration, controls.learner, controls.controller, limits, pusher,
                sample_every=100, sensor_noise=0.0, bias=np.zeros(7), rng=rng, log_rate=100.0,
            )  # fmt: skip
            assert run.error is None
            traces[simulator] = run.loop
        else:
            world.set_scene(task.scene)
            backend = PyBulletBackend(world, participant=pusher, sensor_noise=0.0)
            trace = run_on_loop(
                task, backend, controls.learner, controls.controller, limits, lambda s: None,
                log_rate=100.0, hand=HAND,
            )  # fmt: skip
            traces[simulator] = trace.loop
    native, reference = traces["native"], traces["pybullet"]
    assert native.stop is not None and reference.stop is not None, "nobody drove a joint past 0.3 rad/s"
    a, b = native.stop, reference.stop
    assert (a.reason, a.quantity, a.index, a.tick) == (b.reason, b.quantity, b.index, b.tick) == (
        "joint_velocity", "qd", a.index, a.tick,
    )  # fmt: skip
    np.testing.assert_allclose(a.q, b.q, atol=ATOL_Q)
    assert a.message == b.message
    assert native.held == pytest.approx(reference.held) == pytest.approx(0.5, abs=1.5e-3)
    assert native.ticks == reference.ticks == a.tick + 501
    np.testing.assert_array_equal(native.torque_clips, reference.torque_clips)
    for key in reference.log:
        np.testing.assert_allclose(native.log[key], reference.log[key], atol=1e-9, err_msg=key)
    assert str(native.error) == str(reference.error)


def test_frames_are_rendered_from_the_native_arms_state(world, planners, tmp_path) -> None:
    """A frame of a native episode is PyBullet's picture of the native arm at that tick: the
    PyBullet episode's frame."""
    task = phri.load_task("coffee")
    person = ParticipantParams.draw(np.random.default_rng(7))
    pictures = {}
    for simulator in SIMULATORS:
        result = run_episode(
            task, world, person, EpisodeConfig(simulator=simulator), seed=3, planner=planners["coffee"],
            frame_times=[0.0, 7.505], frame_prefix=tmp_path / simulator,  # 7.505 s: between two looks
        )  # fmt: skip
        assert [p.name for p in result.frames] == [
            f"{simulator}_t00.00.png",
            f"{simulator}_t{7.505:05.2f}.png",
        ]
        pictures[simulator] = [plt_read(p) for p in result.frames]
    for native, reference in zip(pictures["native"], pictures["pybullet"], strict=True):
        assert native.shape == reference.shape == (360, 480, 3)
        np.testing.assert_array_equal(native, reference)
    assert not np.array_equal(pictures["native"][0], pictures["native"][1]), "the arm did not move"


def plt_read(path) -> np.ndarray:
    import matplotlib.image

    return matplotlib.image.imread(path)[:, :, :3]


def test_an_error_ends_a_native_episode_is_raised_and_keeps_the_log(world, planners, tmp_path, monkeypatch):
    """Any error during a native episode (here the person's) ends it, and it is raised after the
    log so far is written, as on PyBullet."""
    task = phri.load_task("table")
    real, calls = Participant.wrench, {"n": 0}

    def failing(self, t, q):
        calls["n"] += 1
        if calls["n"] > 50:  # a second into the task: 50 looks a second
            raise RuntimeError("the person fell over")
        return real(self, t, q)

    monkeypatch.setattr(Participant, "wrench", failing)
    path = tmp_path / "partial.npz"
    with pytest.raises(RuntimeError, match="fell over"):
        run_episode(task, world, ParticipantParams(), planner=planners["table"], log_path=path)
    with np.load(path) as log:
        assert 99 <= len(log["t"]) <= 101
        assert log["t"][-1] == pytest.approx(len(log["t"]) / 100 - 0.01)


def test_a_failed_replan_worker_does_not_end_a_native_episode(world, planners, caplog) -> None:
    task = phri.load_task("table")
    config = EpisodeConfig()
    controls = robot_controls(task, world.model, config, planners["table"], replan_latency=0.001)
    controls.learner._debug_panic_worker()
    rng = np.random.default_rng(1)
    params = ParticipantParams(tolerance=0.002)
    person = Participant(params, task, world.model, planners["table"].desired, rng)
    with caplog.at_level(logging.ERROR, logger="phri.sim.native"):
        run = run_native(
            world, task.start, task.duration, controls.learner, controls.controller, controls.limits, person,
            sample_every=100, sensor_noise=0.1, bias=np.zeros(7), rng=rng, log_rate=100.0,
        )  # fmt: skip
    assert run.error is None and run.loop.stop is None
    assert run.loop.replan_failures >= 1 and run.loop.ticks == 15001
    assert "replans failed" in caplog.text


def test_bad_simulator_input_is_a_clear_error(world) -> None:
    with pytest.raises(InvalidParameterError, match="simulator must be one of"):
        EpisodeConfig(simulator="mujoco")
    model = world.model
    for kwargs, match in (
        ({"dt": 0.0}, "dt"),
        ({"gravity": -1.0}, "gravity"),
        ({"damping": -1.0}, "damping"),
    ):
        with pytest.raises(InvalidParameterError, match=match):
            phri.SimulatedArm(model, **kwargs)
    with pytest.raises(ShapeError, match="damping"):
        phri.SimulatedArm(model, damping=np.zeros(3))
    arm = phri.SimulatedArm(model)
    with pytest.raises(ShapeError, match="tau"):
        arm.step(np.zeros(6))
    task = phri.load_task("coffee")
    controls = robot_controls(task, model, EpisodeConfig(), replan_latency=0.001)
    safety = controls.limits.layer(model, period=1e-3, gravity_compensated=False)
    with pytest.raises(ShapeError, match="q_start"):
        phri.SimulatedLoop(arm, np.zeros(3), safety, duration=1.0, hand=HAND)
    with pytest.raises(phri.exceptions.UnknownNameError, match="nowhere"):
        phri.SimulatedLoop(arm, task.start, safety, duration=1.0, hand="nowhere")
    loop = phri.SimulatedLoop(arm, task.start, safety, duration=1.0, hand=HAND)
    parts = (controls.learner, controls.controller, safety)
    with pytest.raises(ShapeError, match="offsets"):
        loop.advance(20, None, np.zeros((0, 7)), *parts)  # tick 0 is a sample instant
    with pytest.raises(ShapeError, match="push"):
        loop.advance(20, np.zeros(3), np.zeros((1, 7)), *parts)
    with pytest.raises(phri.exceptions.NonFiniteError, match="push"):
        loop.advance(20, np.full(6, np.nan), np.zeros((1, 7)), *parts)
    loop.advance(20, None, np.zeros((1, 7)), *parts)
    assert loop.tick == 20 and loop.ticks == 20 and not loop.done


def test_a_non_finite_step_is_a_simulation_error_that_changes_nothing(world) -> None:
    arm = phri.SimulatedArm(world.model)
    q = phri.load_task("coffee").start
    arm.reset(q)
    with pytest.raises((SimulationError, InvalidParameterError)):
        arm.step(np.full(7, 1e306))
    np.testing.assert_array_equal(arm.q, q)
    np.testing.assert_array_equal(arm.qd, np.zeros(7))


def test_the_study_command_offers_every_simulator() -> None:
    import argparse

    parser = argparse.ArgumentParser()
    _add_study(parser.add_subparsers())
    actions = {a.dest: a for p in parser._subparsers._group_actions[0].choices.values() for a in p._actions}
    assert tuple(actions["simulator"].choices) == SIMULATORS


def test_the_simulator_is_how_a_study_runs_not_what_it_is(tmp_path) -> None:
    from phri.study.calibrate import CalibrationSettings
    from phri.study.errors import StudyConfigError
    from phri.study.protocol import StudyConfig
    from phri.study.run import run_study

    on_pybullet = StudyConfig(simulator="pybullet")
    assert on_pybullet == StudyConfig() and "simulator" not in on_pybullet.to_dict()
    assert on_pybullet.episode_config("learning").simulator == "pybullet"
    assert StudyConfig().episode_config("learning").simulator == "native"
    with pytest.raises(StudyConfigError, match="unknown key"):
        StudyConfig.from_dict({"simulator": "pybullet"})
    with pytest.raises(StudyConfigError, match="simulator"):
        StudyConfig(simulator="mujoco")
    with pytest.raises(InvalidParameterError, match="simulator"):
        run_study(tmp_path / "study", simulator="mujoco")
    assert not (tmp_path / "study").exists()
    with pytest.raises(InvalidParameterError, match="simulator"):
        CalibrationSettings(simulator="mujoco")
    with pytest.raises(InvalidParameterError, match="simulator"):
        phri.demo.run_demo(tmp_path / "demo", simulator="mujoco")
    assert not (tmp_path / "demo").exists()


def test_a_study_runs_on_the_simulator_it_is_given_also_when_resumed(tmp_path, monkeypatch) -> None:
    """The simulator of a StudyConfig (or run_study's) is used, also on a folder whose saved study
    does not record it; with pybullet the native loop never runs."""
    from phri.study.protocol import StudyConfig
    from phri.study.results import load_results
    from phri.study.run import run_study

    config = StudyConfig(
        participants=1, attempts=1, tasks=("human",), familiarization=None, duration=8.0, waypoints=10,
        strategies=("impedance",),
    )  # fmt: skip

    def no_native(*args, **kwargs):
        raise AssertionError("the native loop ran")

    monkeypatch.setattr(phri.sim.episode, "run_native", no_native)
    folder = tmp_path / "study"
    run_study(folder, dataclasses.replace(config, simulator="pybullet"), backend="serial", progress=False)
    assert (load_results(folder)["status"] == "ok").all()
    # Resumed with nothing left to run: the saved study (without a simulator) is the same study.
    run_study(folder, dataclasses.replace(config, simulator="pybullet"), backend="serial", progress=False)
    monkeypatch.undo()
    calls = {"n": 0}
    real = phri.sim.episode.run_native

    def counted(*args, **kwargs):
        calls["n"] += 1
        return real(*args, **kwargs)

    monkeypatch.setattr(phri.sim.episode, "run_native", counted)
    again = tmp_path / "again"
    run_study(again, config, backend="serial", progress=False)
    assert calls["n"] == 1 and (load_results(again)["status"] == "ok").all()
