"""phri's scene server (franky-sim's MuJoCo FR3 with a task's scene, the simulated participant and
injected faults) over the real libfranka protocol, started here on loopback addresses and always
stopped; and, in this process without a network, its frames and wrench arithmetic against phri's
own model of the FR3.

The servers run slowed down (REALTIME) so that a loaded 2-core machine keeps up; lateness is
measured on the robot's clock (RobotState.t), never on the wall clock.
"""

from __future__ import annotations

import collections
import dataclasses
import os
import re
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pylibfranka
import pytest

from phri import Robot
from phri.config import load_task
from phri.exceptions import ConfigError, ConnectionLostError, InvalidParameterError, RobotFaultError
from phri.franka import FrankaBackend, fault_message
from phri.franka.faults import ERROR_NAMES, Fault
from phri.franka.sim_server import READY, SimServer, fr3_task

#: Slow-down of the servers under test: a tick takes this many milliseconds of wall time.
REALTIME = 2.0
FR3 = Robot.fr3()
HAND = FR3.hand_frame
assert HAND is not None


@pytest.fixture(scope="module")
def faults_server() -> Iterator[SimServer]:
    """The bare FR3 (no scene, no person); faults come through the control channel."""
    with SimServer("127.0.15.1", realtime=REALTIME) as server:
        yield server


def control(server: SimServer, ticks: int, fault: str | None = None) -> tuple[list[float], str | None]:
    """Zero torque for up to `ticks` ticks after injecting `fault` (timed into the motion); the
    robot times read and the first fault reported."""
    if fault is not None:
        server.inject(fault)
    backend = FrankaBackend(server.host, FR3, realtime=False)
    times: list[float] = []
    try:
        backend.start(np.zeros(7))
        for _ in range(ticks):
            state = backend.read()
            if state.fault is not None:
                if "aborted control" in state.fault:  # control has ended: every read repeats it
                    assert backend.read() is state
                return times, state.fault
            backend.write(np.zeros(7))
            times.append(state.t)
    finally:
        backend.stop()
    return times, None


# -- frames and wrenches in MuJoCo against phri's model (no network) ---------------------------------

CONFIGS = [
    [0.0, 0.0, 0.0, -1.57, 0.0, 1.57, 0.785],
    [-0.6, 0.3, 0.0, -2.0, 0.0, 2.3, 0.785],
    [0.3, -0.5, 0.2, -2.0, 0.4, 1.8, -0.6],
    [-1.2, 0.8, -0.7, -1.1, -1.5, 2.9, 1.9],
]


@pytest.fixture(scope="module")
def mujoco_fr3() -> Iterator[tuple[object, object]]:
    """franky-sim's MuJoCo FR3, started without a server, and the scene server's push on it."""
    from phri.franka import scene_server

    sim = scene_server._simulator.MujocoSimulator(enable_visualization=False)
    sim.init()
    robot = sim.add_robot()
    sim.start()
    push = scene_server.Push(None, robot)
    push.attach()
    yield sim, push
    sim.cleanup()


def _pose(sim: object, push: object, q: list[float]) -> None:
    from phri.franka.scene_server import mujoco

    data = sim.data  # type: ignore[attr-defined]
    data.qpos[push.qpos] = q  # type: ignore[attr-defined]
    mujoco.mj_kinematics(sim.model, data)  # type: ignore[attr-defined]
    mujoco.mj_comPos(sim.model, data)  # type: ignore[attr-defined]


@pytest.mark.parametrize("q", CONFIGS)
def test_the_tool_point_is_phris_hand_frame(mujoco_fr3: tuple[object, object], q: list[float]) -> None:
    """The point the push acts at, its axes and its Jacobian in franky-sim's MJCF agree with phri's
    URDF (fr3_hand_tcp, libfranka's EE) to 1e-6."""
    from phri.franka.scene_server import mujoco

    sim, push = mujoco_fr3
    _pose(sim, push, q)
    pose = FR3.frame_pose(HAND, q)
    np.testing.assert_allclose(push.tool_point(), pose[:3, 3], atol=1e-6)  # type: ignore[attr-defined]
    hand = sim.data.xmat[push.hand].reshape(3, 3)  # type: ignore[attr-defined]
    np.testing.assert_allclose(hand, pose[:3, :3], atol=1e-6)
    m = sim.model  # type: ignore[attr-defined]
    jacp, jacr = np.zeros((3, m.nv)), np.zeros((3, m.nv))
    mujoco.mj_jac(m, sim.data, jacp, jacr, pose[:3, 3], push.hand)  # type: ignore[attr-defined]
    dofs = push.dofs  # type: ignore[attr-defined]
    np.testing.assert_allclose(np.vstack([jacp[:, dofs], jacr[:, dofs]]), FR3.jacobian(HAND, q), atol=1e-6)


def test_the_push_is_the_persons_wrench_at_the_tool_point(mujoco_fr3: tuple[object, object]) -> None:
    """The applied wrench (at the hand's centre of mass) is the person's wrench at the tool point,
    and the state's external torque is -Jᵀw (libfranka's sign), phri's Jacobian."""
    from phri.franka.scene_server import mujoco

    sim, push = mujoco_fr3
    wrench = np.array([12.0, -7.0, 20.0, 0.5, -1.5, 0.8])

    class Person:
        def wrench(self, t: float, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            return wrench[:3], wrench[3:]

    push.make_person = Person  # type: ignore[attr-defined]
    push.next_person = Person()  # type: ignore[attr-defined]
    try:
        for q in CONFIGS:
            _pose(sim, push, q)
            push.begin_motion()  # type: ignore[attr-defined]
            push(sim)  # type: ignore[operator]
            push.estimate(sim)  # type: ignore[attr-defined]
            j = FR3.jacobian(HAND, q)
            np.testing.assert_allclose(push.tau_ext, -j.T @ wrench, atol=1e-9)  # type: ignore[attr-defined]
            np.testing.assert_allclose(push.o_f_ext, -wrench)  # type: ignore[attr-defined]
            # The generalized force of what MuJoCo applies is Jᵀw at the tool point.
            m, d = sim.model, sim.data  # type: ignore[attr-defined]
            qfrc = np.zeros(m.nv)
            applied = d.xfrc_applied[push.hand]  # type: ignore[attr-defined]
            mujoco.mj_applyFT(m, d, applied[:3], applied[3:], d.xipos[push.hand], push.hand, qfrc)  # type: ignore[attr-defined]
            np.testing.assert_allclose(qfrc[push.dofs], j.T @ wrench, atol=1e-9)  # type: ignore[attr-defined]
            push.end_motion()  # type: ignore[attr-defined]
            push(sim)  # type: ignore[operator]
            push.estimate(sim)  # type: ignore[attr-defined]
            assert not push.tau_ext.any() and not d.xfrc_applied.any()  # type: ignore[attr-defined]
    finally:
        push.make_person = None  # type: ignore[attr-defined]


@pytest.mark.parametrize("name", ["fr3_table", "fr3_laptop", "fr3_human", "fr3_coffee"])
def test_the_tasks_scene_is_in_mujoco_where_phri_puts_it(name: str) -> None:
    """The task's bodies compile with the arm where phri puts them (furniture collides, the person
    is visual only), and the plan for the true weights touches nothing in MuJoCo's own meshes of the
    arm and hand: phri's sphere model keeps it clear in an independent geometry."""
    import xml.etree.ElementTree as ET

    from phri.franka.scene_server import _franky_sim, _simulator, mujoco, scene_bodies

    task = load_task(name)
    sim = _simulator.MujocoSimulator(enable_visualization=False)
    sim.init()
    sim.add_robot()
    for body in scene_bodies(task.scene):
        sim.worldbody.append(body)
    model = mujoco.MjModel.from_xml_string(ET.tostring(sim.scene, encoding="unicode"))
    sim.cleanup()
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    for o in task.scene.objects:
        g = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, f"phri_{o.name}")
        assert g >= 0
        np.testing.assert_allclose(data.geom_xpos[g], o.position, atol=1e-9)
        if o.shape == "box":
            np.testing.assert_allclose(model.geom_size[g], np.asarray(o.size) / 2)
        if o.shape == "cylinder":
            np.testing.assert_allclose(model.geom_size[g][:2], [o.radius, o.length / 2])
        collides = model.geom_contype[g] != 0 or model.geom_conaffinity[g] != 0
        assert collides == (o.kind != "person"), o.name
    joints = [
        mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, f"robot0_fr3_joint{i}") for i in range(1, 8)
    ]
    for i in (1, 2):  # the fingers open as franky-sim starts them (closed, they touch each other)
        finger = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, f"robot0_finger_joint{i}")
        data.qpos[model.jnt_qposadr[finger]] = _franky_sim.DEFAULT_HAND_INITIAL_WIDTH / 2
    for q in _plan(task):
        data.qpos[model.jnt_qposadr[joints]] = q
        mujoco.mj_forward(model, data)
        touching = {
            tuple(
                mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, model.geom_bodyid[g])
                for g in (c.geom1, c.geom2)
            )
            for c in data.contact[: data.ncon]
        }
        assert not touching, f"{name}: the plan touches {touching} at q={q}"


def _plan(task: object) -> np.ndarray:
    """The plan for `task`'s true weights (phri's planner, as the participant uses it)."""
    from types import SimpleNamespace

    from phri.sim.episode import Planner

    return Planner(task, SimpleNamespace(model=FR3)).desired  # type: ignore[arg-type]


# -- faults over the protocol ----------------------------------------------------------------------


def test_every_error_name_reaches_pylibfranka_as_itself(faults_server: SimServer) -> None:
    """ERROR_NAMES is the robot's wire order: each injected error arrives as that one libfranka
    Errors attribute, and fault_message reads it from the real pylibfranka state."""
    attributes = {n for n in dir(pylibfranka.Errors) if not n.startswith("_")}
    assert attributes == set(ERROR_NAMES)
    robot = pylibfranka.Robot(faults_server.host, pylibfranka.RealtimeConfig.kIgnore)
    try:
        assert fault_message(robot.read_once()) is None
        for name in ERROR_NAMES:
            faults_server.inject(f"reflex:{name}")
            deadline = time.monotonic() + 5
            while not (state := robot.read_once()).current_errors and time.monotonic() < deadline:
                time.sleep(0.01)
            errors = state.current_errors
            assert [n for n in ERROR_NAMES if getattr(errors, n)] == [name]
            assert str(errors).count('"') == 2  # libfranka's own list names one error too
            assert state.robot_mode == pylibfranka.RobotMode.Reflex
            message = fault_message(state)
            assert message == (
                f"the robot reports robot mode Reflex; errors: {name}: the robot stopped itself (a "
                "collision or limit reflex); clear the cause, then call automatic_error_recovery() "
                "(phri does so on the next connect)"
            )
            robot.automatic_error_recovery()
            while (state := robot.read_once()).robot_mode != pylibfranka.RobotMode.Idle:
                assert time.monotonic() < deadline  # states sent before the recovery may be queued
            assert fault_message(state) is None
            assert getattr(state.last_motion_errors, name) is True  # kept until the next motion
    finally:
        robot.stop()
        del robot


def test_a_reflex_aborts_control_with_its_errors_and_start_recovers(faults_server: SimServer) -> None:
    times, fault = control(faults_server, 2000, "reflex:joint_velocity_violation,joint_reflex@0.1")
    assert fault is not None and 0.09 <= times[-1] <= 0.1  # on the robot's clock, whatever the load
    assert 'motion aborted by reflex! ["joint_velocity_violation", "joint_reflex"]' in fault
    assert "automatic_error_recovery()" in fault
    # The robot stays in Reflex; a new start sees it, recovers and controls again.
    robot = pylibfranka.Robot(faults_server.host, pylibfranka.RealtimeConfig.kIgnore)
    state = robot.read_once()
    assert state.robot_mode == pylibfranka.RobotMode.Reflex  # a new connection reads a fresh state
    assert "errors: joint_velocity_violation, joint_reflex" in str(fault_message(state))
    del robot
    times, fault = control(faults_server, 50)
    assert fault is None and len(times) == 50


def test_the_user_stop_aborts_control_and_refuses_a_start_until_released(faults_server: SimServer) -> None:
    times, fault = control(faults_server, 2000, "user_stop:0.3@0.05")
    assert fault is not None and 0.04 <= times[-1] <= 0.05
    assert fault == (
        "the robot aborted control: libfranka: Move command aborted: User Stop pressed!; the user stop "
        "is pressed; release it, then restart the episode"
    )
    with pytest.raises(
        RobotFaultError, match=r"robot mode UserStopped: .*automatic error recovery was refused"
    ):
        control(faults_server, 10)
    robot = pylibfranka.Robot(faults_server.host, pylibfranka.RealtimeConfig.kIgnore)
    deadline = time.monotonic() + 30
    while robot.read_once().robot_mode == pylibfranka.RobotMode.UserStopped:  # 0.3 s of robot time
        assert time.monotonic() < deadline
    del robot
    times, fault = control(faults_server, 50)
    assert fault is None and len(times) == 50


def test_a_nan_in_the_state_is_a_fault_naming_it(faults_server: SimServer) -> None:
    times, fault = control(faults_server, 2000, "nan:dq@0.05")
    assert 0.04 <= times[-1] <= 0.05
    assert fault is not None and fault.startswith("the robot's state has non-finite values (dq[0]=nan, ")
    assert "q[0]" not in fault.replace("dq[0]", "")


def test_late_ticks_show_on_the_robots_clock(faults_server: SimServer) -> None:
    times, fault = control(faults_server, 300, "late:25@0.1")
    assert fault is None
    steps = np.round(np.diff(times) * 1e3).astype(int)
    # The robot's clock runs on while the client hears nothing: one jump of 25 ms. Any other
    # late tick would be this machine's own lateness, measured the same way.
    assert 25 in steps and steps.min() >= 1
    assert np.sum(steps == 25) == 1


@pytest.mark.parametrize("fault", ["drop@0.05", "stall:1.5@0.05"])
def test_a_dropped_or_stalled_link_is_a_lost_connection(faults_server: SimServer, fault: str) -> None:
    began = time.monotonic()
    # libfranka reports its receive timeout, or (when the server's side gives up first) the closed
    # connection: either way a lost connection, never a hang.
    with pytest.raises(
        ConnectionLostError,
        match=r"host '127.0.15.1': the robot stopped answering: .*(Timeout|server closed connection)",
    ):
        control(faults_server, 5000, fault)
    assert time.monotonic() - began < 10  # libfranka's own receive timeout (1 s), never a hang
    if fault.startswith("stall"):
        time.sleep(0.5)  # the server sleeps out its stall before the next test connects


def test_faults_are_parsed_and_refused_clearly() -> None:
    assert Fault.parse("reflex") == Fault("reflex", errors=("joint_reflex",))
    assert Fault.parse(" late:5@1.5 ") == Fault("late", 1.5, ticks=5)
    assert Fault.parse("user_stop") == Fault("user_stop", seconds=1.0)
    for spec in (
        "reflex:cartesian_reflex@0.25",
        "user_stop:2",
        "nan:tau_ext",
        "late:3",
        "stall:0.5@2",
        "drop@0",
    ):
        assert Fault.parse(spec).spec() == spec
    # spec() is what SimServer hands its child: a time keeps every digit (not six, which moved
    # this one to another tick).
    assert Fault.parse("nan:dq@1234.5678").spec() == "nan:dq@1234.5678"
    assert Fault.parse("stall:0.1234567@0.1").spec() == "stall:0.1234567@0.1"
    for spec, message in [
        ("reflex:joint_wobble", "unknown libfranka error joint_wobble"),
        ("nan:qdd", "nan takes one of q, dq, tau_ext"),
        ("late:1", r"late:N takes a whole number of ticks in \[2,"),
        ("late:x", "late:N .ticks. must be a number"),
        ("stall:0", r"stall:S takes seconds in \(0, 60\]"),
        ("drop:1", "KIND one of reflex, user_stop, nan, late, stall, drop"),
        ("user_stop:-1", r"user_stop:S takes seconds in \(0, 60\]"),
        ("reflex@-1", "@T must be a robot time >= 0 s"),
        ("nan@inf", "must be finite"),
    ]:
        with pytest.raises(InvalidParameterError, match=message):
            Fault.parse(spec)


# -- the scene and the person ------------------------------------------------------------------------


def test_the_person_pushes_the_hand_and_the_robot_measures_j_transpose_w() -> None:
    """The table task: the hand is lifted for 0.3 s, then left free (zero torque); the participant
    sees the cup too high and pushes the hand down, the hand moves along the push, and tau_ext is
    phri's Jᵀ·w."""
    with SimServer("127.0.15.2", realtime=REALTIME, task="table", seed=3) as server:
        backend = FrankaBackend(server.host, FR3, realtime=False)
        rows = []
        try:
            first = backend.start(np.zeros(7))
            np.testing.assert_allclose(first.q, load_task("fr3_table").start, atol=1e-4)
            for k in range(1500):
                state = backend.read()
                assert state.fault is None
                up = np.array([0, 0, 15.0, 0, 0, 0])  # N: a lift for the first 0.3 s
                backend.write(FR3.jacobian(HAND, state.q).T @ up if k < 300 else np.zeros(7))
                wrench = -np.asarray(backend.raw.O_F_ext_hat_K)  # the person's, on the robot
                rows.append((state.t, state.q, state.tau_ext, wrench))
        finally:
            backend.stop()
    t = np.array([r[0] for r in rows])
    q = np.array([r[1] for r in rows])
    tau = np.array([r[2] for r in rows])
    w = np.array([r[3] for r in rows])
    pushing = np.linalg.norm(w[:, :3], axis=1) > 1.0
    assert 0 < np.argmax(pushing) and pushing.sum() > 200, "the person never pushed"
    onset = int(np.argmax(pushing))
    # tau_ext is the push through phri's Jacobian of the hand (MuJoCo computed it), at every tick.
    for k in np.nonzero(np.any(w != 0, axis=1))[0]:
        expected = FR3.jacobian(HAND, q[k]).T @ w[k]
        np.testing.assert_allclose(tau[k], expected, atol=1e-3 + 2e-3 * np.abs(expected).max())
    assert np.all(tau[np.all(w == 0, axis=1)] == 0.0)  # hands off: nothing measured
    # Once the lift ends, the push changes the hand's velocity along itself (the arm is free: zero
    # torque, gravity compensated).
    start = max(onset, 300)
    window = slice(start, start + 100)
    assert pushing[window].all(), "the person pushes on after the lift"
    hand = np.array([FR3.frame_pose(HAND, qk)[:3, 3] for qk in q[window]])
    tw = t[window]
    gained = (hand[-1] - hand[-11]) / (tw[-1] - tw[-11]) - (hand[10] - hand[0]) / (tw[10] - tw[0])
    force = w[window, :3].mean(axis=0)
    assert np.linalg.norm(gained) > 1e-3
    assert gained @ force / (np.linalg.norm(gained) * np.linalg.norm(force)) > 0.7
    # The robot's clock: one millisecond per tick but for this machine's own late ticks.
    steps = np.round(np.diff(t) * 1e3)
    assert steps.min() >= 1 and np.mean(steps == 1) > 0.9


def test_the_server_process_is_gone_after_its_block_even_on_an_error() -> None:
    with pytest.raises(RuntimeError, match="inside"):
        with SimServer("127.0.15.3", realtime=REALTIME) as server:
            assert server.process is not None
            pid = server.process.pid
            raise RuntimeError("inside")
    assert server.process is None
    with pytest.raises(ProcessLookupError):
        os.kill(pid, 0)
    with pytest.raises(ConnectionLostError, match="not running"):
        server.inject("drop")


def test_the_server_stops_when_its_control_channel_closes() -> None:
    """A SimServer's process killed without leaving its block (kill -9, a crash) closes the child's
    stdin, the control channel: the child stops rather than serve on, orphaned."""
    with SimServer("127.0.15.6", realtime=REALTIME) as server:
        process = server.process
        assert process is not None and process.stdin is not None
        process.stdin.close()
        assert process.wait(timeout=30) == 0
        deadline = time.monotonic() + 5  # the output is read in a thread
        while not any("control channel closed" in line for line in server.lines):
            assert time.monotonic() < deadline, list(server.lines)
            time.sleep(0.01)


def test_a_server_that_fails_to_start_is_killed(monkeypatch: pytest.MonkeyPatch) -> None:
    """__exit__ does not run when __enter__ raises (here Ctrl-C while it waits for the port):
    __enter__ itself kills the child."""
    import phri.franka.sim_server as sim_server

    def interrupted(*args: object, **kwargs: object) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(sim_server.socket, "create_connection", interrupted)
    server = SimServer("127.0.15.7", realtime=REALTIME)
    try:
        with pytest.raises(KeyboardInterrupt):
            server.__enter__()
        assert server.process is None, "the child was left running"
    finally:
        server.stop()


def test_stopping_a_server_while_its_output_is_read_leaves_no_thread_error(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """stop() closed the child's output under the thread reading it, which then failed (an
    unhandled thread exception: an error of whichever test pytest noticed it in); a child that
    writes much (--log-protocol, many faults) met it. A stand-in child writes without end, and
    keeping each line takes a while, so that the reader is always busy when stop() comes."""
    import phri.franka.sim_server as sim_server

    chatty = f"print({READY!r} + ' 127.0.15.8', flush=True)\nwhile True:\n    print('x' * 200, flush=True)\n"
    monkeypatch.setattr(SimServer, "command", lambda self: [sys.executable, "-c", chatty])

    class Answered:
        def close(self) -> None:
            pass

    monkeypatch.setattr(sim_server.socket, "create_connection", lambda *args, **kwargs: Answered())

    class SlowLines(collections.deque):
        """Keeping a line takes a while: the reader is between two reads when stop() comes."""

        def append(self, line: str) -> None:
            time.sleep(1e-3)
            super().append(line)

    for _ in range(3):
        server = SimServer("127.0.15.8")
        server.lines = SlowLines(maxlen=100)
        with server:
            time.sleep(0.05)
        assert server.lines, "the output read is kept"


# -- phri sim-server ------------------------------------------------------------------------------


def test_sim_server_serves_a_task_until_ctrl_c(tmp_path: Path) -> None:
    population = tmp_path / "lab.toml"
    population.write_text(STRONG)
    command = [sys.executable, "-m", "phri", "sim-server", "--task", "human", "--host", "127.0.15.4",
               "--population", str(population)]  # fmt: skip
    # Started with SIGINT ignored, as a shell starts a background job: Ctrl-C must stop it all the same.
    process = subprocess.Popen(
        command + ["--realtime", "2", "--seed", "5"], stdout=subprocess.PIPE, text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN),
    )  # fmt: skip
    try:
        assert process.stdout is not None
        line = process.stdout.readline()
        assert line.startswith(
            f"{READY} 127.0.15.4 (task fr3_human, participant seed 5 of population {population}, 2x slower"
        )
        robot = pylibfranka.Robot("127.0.15.4", pylibfranka.RealtimeConfig.kIgnore)
        assert robot.read_once().robot_mode == pylibfranka.RobotMode.Idle
        del robot
        process.send_signal(signal.SIGINT)
        process.communicate(timeout=60)  # seconds on a loaded machine
        assert process.returncode == 0
    finally:
        if process.poll() is None:
            process.kill()
        process.wait(timeout=10)
        process.stdout.close()  # type: ignore[union-attr]


@pytest.mark.parametrize(
    ("arguments", "message"),
    [
        (
            ["--task", "table", "--host", "10.0.0.1"],
            "host must be a loopback address 127.x.y.z, got '10.0.0.1'",
        ),
        (["--task", "laptop", "--host", "localhost"], "host must be a loopback address"),
        (["--task", "nowhere"], "task: unknown task 'nowhere'"),
        (["--task", "table", "--realtime", "0"], r"realtime must be a slow-down factor in \(0, 100\]"),
        (["--task", "table", "--fault", "reflex:oops"], "unknown libfranka error oops"),
        (["--task", "table", "--seed", "-1"], "--seed must be >= 0"),
        (["--task", "table", "--population", "nobody.toml"], "nobody.toml: population file not found"),
    ],
)
def test_sim_server_refuses_bad_input(
    arguments: list[str], message: str, capsys: pytest.CaptureFixture[str]
) -> None:
    from phri.cli import main

    assert main(["sim-server", *arguments]) == 2
    err = capsys.readouterr().err
    assert err.startswith("phri sim-server: error: ")
    assert __import__("re").search(message, err), err


#: A lab's population: phri's default but for a fixed, strong push.
STRONG = 'extends = "default"\n[parameters.max_force]\ndistribution = "fixed"\nvalue = 25.0\n'


def test_the_servers_participant_is_drawn_from_the_population_it_is_given(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from phri.franka.scene_server import participant_for
    from phri.sim.participant import default_population, load_population

    lab = tmp_path / "lab.toml"
    lab.write_text(STRONG)
    task = load_task("fr3_table")
    default = participant_for(task, FR3, seed=4)().params
    assert default == default_population().draw_from(np.random.default_rng(4))
    person = participant_for(task, FR3, seed=4, population=load_population(lab))().params
    assert person.max_force == 25.0 != default.max_force
    assert dataclasses.replace(person, max_force=default.max_force) == default  # the same draw otherwise
    assert SimServer("127.0.15.9", task="table", population=lab).command()[-2:] == ["--population", str(lab)]
    # A file named like a shipped population is the file: the child is given its absolute path.
    (tmp_path / "default").write_text(STRONG)
    monkeypatch.chdir(tmp_path)
    named = SimServer("127.0.15.9", task="table", population=Path("default")).command()[-1]
    assert named == str(tmp_path / "default")
    bad = tmp_path / "bad.toml"
    bad.write_text(STRONG.replace("value = 25.0", "value = -25.0"))
    with pytest.raises(ConfigError, match=f"^{re.escape(str(bad))}: key 'parameters.max_force.value'"):
        SimServer("127.0.15.9", task="table", population=bad)


def test_a_task_for_another_robot_is_a_clear_error(capsys: pytest.CaptureFixture[str]) -> None:
    from importlib import resources

    from phri.cli import main

    jaco2_table = str(resources.files("phri").joinpath("tasks", "table.toml"))
    with pytest.raises(
        ConfigError, match=r"table.toml is posed for robot 'jaco2', but the simulator is an FR3"
    ):
        fr3_task(jaco2_table)
    with pytest.raises(ConfigError, match="posed for robot 'jaco2'"):
        SimServer("127.0.15.5", task=jaco2_table)
    assert main(["sim-server", "--task", jaco2_table]) == 2
    assert "use an FR3 task (fr3_coffee, fr3_human, fr3_laptop, fr3_table)" in capsys.readouterr().err
    # Shipped FR3 tasks by their short name or their own.
    assert fr3_task("table").name == fr3_task("fr3_table").name == "fr3_table"
