"""phri's scene server: franky-sim's MuJoCo FR3 (``phri[franka-sim]``, pinned: this module relies on
franky-sim 1.0.4's internals) with a task's scene, the simulated participant pushing the hand, the
person's push in the robot's external-torque estimate, and injected faults.

What it adds to franky-sim, per 1 ms tick:

- **Scene.** The task's ``[scene.*]`` objects are MuJoCo bodies added before start, placed as phri
  places them (base frame = MuJoCo's world). Furniture (table, laptop) collides with the arm, as it
  would. The person is drawn but does not collide: their body is soft and moves aside, and a rigid
  cylinder would hit the arm with forces no person exerts; they act on the arm only through the push.
- **Push.** During a torque-control motion that begins at the task's start pose (every joint within
  :data:`phri.franka.move.START_TOLERANCE` of it; during any other, such as the move that brings
  the arm there, the person stands back) the participant (:func:`participant_for`) watches the
  arm (its joint positions, the robot's time since the motion started) and pushes: before each
  physics step its wrench (force [N] at the hand's tool point, torque [N·m], base frame) is MuJoCo's
  applied wrench ``xfrc_applied`` on the hand body, moved from the tool point to the body's centre
  of mass.
- **External torque.** ``tau_ext_hat_filtered`` reports the push as an FR3 estimates it, in
  libfranka's sign convention (the torque the robot exerts on its surroundings; libfranka documents
  it as τ_J minus the model's torque): −Jᵀ·w with J MuJoCo's Jacobian of the tool point and w the
  person's wrench on the robot. franky-sim reports the commanded joint torques there instead.
  Contacts with the furniture are not in it.
- **Faults** (:mod:`phri.franka.faults`): a schedule given at start, and a control channel (one
  fault per line on the server's standard input).

:func:`serve` runs it until interrupted; ``phri sim-server`` and :class:`phri.franka.sim_server.SimServer`
(a child process for tests) call it.
"""

from __future__ import annotations

import importlib
import logging
import queue
import threading
import time
import xml.etree.ElementTree as ET
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any, TextIO, cast

import numpy as np

from phri._extras import require
from phri._phri import Robot, Scene, SceneObject
from phri.config import Task
from phri.exceptions import InvalidParameterError
from phri.franka.faults import ERROR_NAMES, Fault
from phri.franka.move import START_TOLERANCE
from phri.franka.sim_server import READY

if TYPE_CHECKING:
    from phri.sim.participant import Population

__all__ = ["build_server", "participant_for", "scene_bodies", "serve"]

#: Where the server reports (its ready line, injected and refused faults): one line per call.
Report = Callable[[str], None]
logger = logging.getLogger(__name__)


def _log(line: str) -> None:
    """The default report: phri's log (the command line prints instead)."""
    logger.info(line)


#: The simulator's step [s] (franky-sim's, one libfranka tick).
TICK = 1e-3
#: Connections the command port queues while one is being served.
LISTEN_BACKLOG = 8
#: Colours of scene bodies (RGBA): furniture, the person.
FURNITURE_RGBA = "0.55 0.4 0.25 1"
PERSON_RGBA = "0.9 0.7 0.55 0.6"

# franky-sim (pinned) and MuJoCo, its dependency; neither ships type information.
_franky_sim: Any = require("franky_sim", "the Franka simulator")
_protocol: Any = require("franky_sim.franka_robot_protocol", "the Franka simulator")
_simulator: Any = require("franky_sim.mujoco_simulator", "the Franka simulator")
mujoco: Any = importlib.import_module("mujoco")
_RobotServer: Any = _franky_sim.FrankaRobotServer
_SimulationServer: Any = _franky_sim.SimulationServer
_Recovery: Any = _protocol.AutomaticErrorRecoveryCommand


def participant_for(
    task: Task, robot: Robot, seed: int, dt: float = TICK, population: Population | None = None
) -> Callable[[], Any]:
    """A maker of the study's simulated participant for `task` on `robot`, seeded with `seed`: each
    call gives a fresh person (the same one for the same seed), their parameters drawn from
    `population` (None: phri's default) with `seed`, their desired behaviour the plan for the task's
    true weights (phri's planner, as in simulation; made once, here). The one place the scene server
    makes a participant."""
    from types import SimpleNamespace

    from phri._phri import TimedTrajectory
    from phri.sim.episode import Planner
    from phri.sim.participant import Participant, default_population
    from phri.sim.world import World

    # The planner reads only the world's model; the scene server has no PyBullet world.
    planner = Planner(task, cast(World, SimpleNamespace(model=robot)))
    desired = TimedTrajectory(planner.desired, task.duration)
    drawn_from = default_population() if population is None else population

    def make() -> Any:
        params = drawn_from.draw_from(np.random.default_rng(seed))
        # The person's own random stream, as an episode spawns it from the same seed.
        person_rng = np.random.default_rng(np.random.SeedSequence(seed).spawn(2)[0])
        return Participant(params, task, robot, desired, person_rng, dt=dt)

    return make


def scene_bodies(scene: Scene) -> list[ET.Element]:
    """One MJCF ``<body>`` per object of `scene`, placed in the base frame: furniture collides, a
    person (``kind = "person"``) is visual only."""
    return [_body(o) for o in scene.objects]


def _body(o: SceneObject) -> ET.Element:
    pose = np.asarray(o.pose, dtype=float)
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, np.ascontiguousarray(pose[:3, :3]).ravel())
    body = ET.Element("body", name=f"phri_{o.name}", pos=_vec(pose[:3, 3]), quat=_vec(quat))
    geom = ET.SubElement(body, "geom", name=f"phri_{o.name}")
    if o.shape == "box":
        geom.set("type", "box")
        geom.set("size", _vec(np.asarray(o.size) / 2))  # MuJoCo takes half extents
    elif o.shape == "cylinder":
        geom.set("type", "cylinder")
        geom.set("size", _vec([o.radius, (o.length or 0.0) / 2]))  # radius, half length (along z)
    elif o.shape == "sphere":
        geom.set("type", "sphere")
        geom.set("size", _vec([o.radius]))
    elif o.shape == "plane":
        geom.set("type", "plane")
        geom.set("size", "0 0 0.05")  # infinite
    else:  # pragma: no cover - SceneObject knows no other shape
        raise InvalidParameterError(f"scene object '{o.name}': shape {o.shape!r} has no MuJoCo body")
    if o.kind == "person":
        geom.set("contype", "0")
        geom.set("conaffinity", "0")
        geom.set("rgba", PERSON_RGBA)
    else:
        geom.set("rgba", FURNITURE_RGBA)
    return body


def _vec(values: Any) -> str:
    return " ".join(f"{float(v):.9g}" for v in values)


class Push:
    """The participant's push on the simulated FR3: a pre-step callback that applies it, and a
    post-step one that keeps the external torque an FR3 would estimate (libfranka's sign).

    `start`: the task's start pose [rad]; the person takes part only in a motion that begins there
    (None: in every motion)."""

    def __init__(
        self, make_person: Callable[[], Any] | None, robot: Any, start: np.ndarray | None = None
    ) -> None:
        self.make_person = make_person
        self.robot = robot  # franky-sim's FrankaMujocoRobot (attached to the scene)
        self.start = None if start is None else np.asarray(start, dtype=float)
        self.person: Any = None
        #: The person for the next motion, made ahead (making one samples the desired plan at 1 kHz:
        #: tens of ms that must not fall in a motion's first tick).
        self.next_person: Any = None
        #: Robot time [s] since the current torque-control motion started (None: none runs).
        self.t: float | None = None
        #: The person's wrench on the robot this tick: force [N], torque [N·m] about the tool point.
        self.wrench = np.zeros(6)
        #: libfranka's tau_ext_hat_filtered [N·m] for the state after this tick.
        self.tau_ext = np.zeros(7)
        #: libfranka's O_F_ext_hat_K and K_F_ext_hat_K (K = EE): the wrench the robot exerts [N, N·m],
        #: in the base frame and in the EE frame.
        self.o_f_ext = np.zeros(6)
        self.k_f_ext = np.zeros(6)
        self._model: Any = None

    def attach(self) -> None:
        m = self.robot.model
        self._model = m
        self.hand = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "robot0_hand")
        # The tool point in the hand body's frame: franky-sim's (and libfranka's default) F_T_EE.
        self.tcp_in_hand = np.array(self.robot.robot_parameters.ee_tcp_xyz, dtype=float)
        self.dofs = np.array(self.robot._dof_addrs)
        self.qpos = np.array(self.robot._qpos_addrs)
        self._jacp = np.zeros((3, m.nv))
        self._jacr = np.zeros((3, m.nv))
        self.next_person = self.make_person() if self.make_person is not None else None

    def begin_motion(self) -> None:
        """A torque-control motion starts: the person's clock starts at 0 (a fresh person, the same
        seed: every motion that begins at the task's start is one episode). A motion that begins
        elsewhere (the move to the start) goes on without them: they wait for the next."""
        self.t = 0.0
        if self.start is not None and self.next_person is not None:
            q = self.robot.data.qpos[self.qpos]
            if np.abs(q - self.start).max() > START_TOLERANCE:
                self.person = None
                return
        self.person, self.next_person = self.next_person, None

    def end_motion(self) -> None:
        self.t, self.person = None, None
        if self.next_person is None and self.make_person is not None:
            self.next_person = self.make_person()

    def tool_point(self) -> np.ndarray:
        """World position of the tool point (libfranka's EE) after the last kinematics [m]."""
        d = self.robot.data
        return d.xpos[self.hand] + d.xmat[self.hand].reshape(3, 3) @ self.tcp_in_hand

    def __call__(self, sim: Any) -> None:
        """Before a physics step: the person's wrench for this tick, applied to the hand."""
        d = self.robot.data
        d.xfrc_applied[self.hand] = 0.0
        self.wrench[:] = 0.0
        if self.t is None:
            return
        t = self.t
        self.t = t + TICK
        if self.person is None:
            return
        push = self.person.wrench(t, d.qpos[self.qpos])
        if push is None:
            return
        force, torque = (np.asarray(v, dtype=float) for v in push)
        self._kinematics()  # this step's positions (the last step's are one tick old)
        point = self.tool_point()
        # xfrc_applied acts at the body's centre of mass: the same wrench, moved there.
        d.xfrc_applied[self.hand, :3] = force
        r = point - d.xipos[self.hand]
        moment = (
            r[1] * force[2] - r[2] * force[1],
            r[2] * force[0] - r[0] * force[2],
            r[0] * force[1] - r[1] * force[0],
        )
        d.xfrc_applied[self.hand, 3:] = torque + moment  # r × f by hand: np.cross costs 0.1 ms
        self.wrench[:3], self.wrench[3:] = force, torque

    def estimate(self, sim: Any) -> None:
        """After a physics step: the external torque and wrench the robot reports with the state
        of the step's end (libfranka's signs: what the robot exerts on its surroundings)."""
        for kept in (self.tau_ext, self.o_f_ext, self.k_f_ext):
            kept[:] = 0.0
        if not self.wrench.any():
            return
        m, d = self._model, self.robot.data
        self._kinematics()
        point = self.tool_point()
        mujoco.mj_jac(m, d, self._jacp, self._jacr, point, self.hand)
        force, torque = self.wrench[:3], self.wrench[3:]
        self.tau_ext[:] = -(self._jacp[:, self.dofs].T @ force + self._jacr[:, self.dofs].T @ torque)
        self.o_f_ext[:] = -self.wrench
        rotation = d.xmat[self.hand].reshape(3, 3)  # the hand body's axes are the EE's (F_T_EE)
        self.k_f_ext[:3], self.k_f_ext[3:] = rotation.T @ -force, rotation.T @ -torque

    def _kinematics(self) -> None:
        """MuJoCo's positions and joint axes for the current q (mj_jac reads mj_comPos's axes)."""
        m, d = self._model, self.robot.data
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)


class SceneRobotServer(_RobotServer):
    """franky-sim's FR3 server reporting the person's push as the external torque, and the robot's
    own reflex and error states when a fault is injected."""

    def __init__(self, robot: Any, hostname_candidates: Any, push: Push) -> None:
        super().__init__(robot, hostname_candidates)
        self.push = push
        self.reflex: tuple[bool, ...] | None = None  # the active errors while in Reflex mode
        self.user_stop_ticks = 0  # ticks the user stop stays pressed
        self.last_motion_errors: tuple[bool, ...] = (False,) * len(ERROR_NAMES)
        self.nan_field: str | None = None
        self.torque_motion = False
        # franky-sim acknowledges error recovery without an error state; phri's clears the reflex.
        commands = self._FrankaServer__command_class_map
        commands[_protocol.RobotCommand.kAutomaticErrorRecovery] = _RecoveryCommand

    def init(self) -> None:
        super().init()
        # franky-sim listens with a backlog of one: a client's connection arriving while a port
        # probe (phri's FrankaBackend and SimServer probe first) waits to be accepted was dropped,
        # and libfranka gave up after its 1 s timeout. Listening again only deepens the queue.
        self._FrankaServer__server_socket.listen(LISTEN_BACKLOG)

    # -- motions -------------------------------------------------------------------------------

    def start_motion(self, controller_mode: Any, motion_generator_mode: Any, motion_id: int) -> None:
        if self.reflex is not None or self.user_stop_ticks:
            # A stopped robot refuses motions (MoveCommand answers Aborted).
            raise RuntimeError("the robot is in Reflex or UserStopped mode")
        super().start_motion(controller_mode, motion_generator_mode, motion_id)
        self.last_motion_errors = (False,) * len(ERROR_NAMES)
        self.torque_motion = controller_mode == _protocol.MoveCommandControllerMode.kExternalController
        if self.torque_motion:
            self.push.begin_motion()

    def stop_motion(self, send_preemption_signal: bool = True) -> None:
        super().stop_motion(send_preemption_signal)
        self._end_torque_motion()

    def _handle_udp_command(self, command_data: bytes) -> None:
        super()._handle_udp_command(command_data)
        if self.current_motion_id == 0:  # the client finished its motion
            self._end_torque_motion()

    def _reset_state(self) -> None:  # a client disconnected or a new one connected
        super()._reset_state()
        self._end_torque_motion()

    def _end_torque_motion(self) -> None:
        if getattr(self, "torque_motion", False):
            self.torque_motion = False
            self.push.end_motion()

    # -- faults --------------------------------------------------------------------------------

    def inject_reflex(self, errors: Sequence[str]) -> None:
        """The robot's reflex with `errors` set: Reflex mode, the motion aborted (ReflexAborted)."""
        bits = tuple(name in errors for name in ERROR_NAMES)
        self.reflex = self.last_motion_errors = bits
        self._abort(_protocol.MoveStatus.kReflexAborted)

    def inject_user_stop(self, ticks: int) -> None:
        """The user stop pressed for `ticks` ticks: UserStopped mode, the motion aborted
        (EmergencyAborted); released, the robot is idle again without a recovery."""
        self.user_stop_ticks = max(1, ticks)
        self._abort(_protocol.MoveStatus.kEmergencyAborted)

    def tick(self) -> None:
        """One tick passed (the user stop is released when its time is up)."""
        if self.user_stop_ticks:
            self.user_stop_ticks -= 1

    def _abort(self, status: Any) -> None:
        """Aborts a running motion with `status` (libfranka raises a ControlException on it); the
        arm holds where it is."""
        motion_id = self.current_motion_id
        if motion_id:
            self.stop_motion(send_preemption_signal=False)
            _protocol.BaseCommand.send_response(
                self._tcp_socket, _protocol.RobotCommand.kMove, motion_id, status
            )
            self.reset_current_motion_id()

    def recover(self) -> Any:
        """automatic_error_recovery(): clears a reflex (the last motion's errors stay); refused
        while the user stop is pressed."""
        if self.user_stop_ticks:
            return _protocol.AutomaticErrorRecoveryStatus.kCommandRejectedDueToActivatedSafetyFunctions
        self.reflex = None
        return _protocol.AutomaticErrorRecoveryStatus.kSuccess

    def drop(self) -> None:
        """Closes the client's connection (TCP and UDP), as a pulled cable would end it."""
        self.reset_state()

    @property
    def robot_state(self) -> Any:
        state = super().robot_state
        push = self.push
        changes: dict[str, Any] = {
            "tau_ext_hat_filtered": tuple(push.tau_ext.tolist()),
            "O_F_ext_hat_K": tuple(push.o_f_ext.tolist()),
            "K_F_ext_hat_K": tuple(push.k_f_ext.tolist()),
        }
        if self.user_stop_ticks:
            changes["robot_mode"] = _protocol.RobotMode.kUserStopped
        elif self.reflex is not None:
            changes.update(
                robot_mode=_protocol.RobotMode.kReflex, errors=self.reflex, reflex_reason=self.reflex
            )
        elif any(self.last_motion_errors):
            changes["reflex_reason"] = self.last_motion_errors
        if self.nan_field is not None:
            field = {"tau_ext": "tau_ext_hat_filtered"}.get(self.nan_field, self.nan_field)
            changes[field] = (float("nan"),) * 7
            self.nan_field = None
        return state.replace(**changes)


class _RecoveryCommand(_Recovery):
    def handle(self, server: Any) -> None:
        self.reply(server.recover())


class SceneServer(_SimulationServer):
    """franky-sim's loop with phri's robot server, the push before each step and the faults."""

    def __init__(
        self,
        sim: Any,
        host: str,
        push: Push,
        schedule: Sequence[Fault] = (),
        channel: queue.SimpleQueue[Fault] | None = None,
        report: Report | None = None,
    ) -> None:
        super().__init__(sim, hostname_candidates=[host])
        self.push = push
        self.pending = list(schedule)
        self.channel = channel
        self.report = report or _log
        self.late_ticks = 0

    def init(self) -> None:
        robot = self.sim.robots[0]
        rs = SceneRobotServer(robot, self._remaining_hostname_candidates, self.push)
        rs.init()
        self.robot_servers.append(rs)
        self.sim.start()
        self.push.attach()
        self.sim.register_pre_step_callback(self.push)
        self.sim.register_post_step_callback(self.push.estimate)

    def cleanup(self) -> None:
        try:
            super().cleanup()
        finally:
            if not self.sim.is_cleaned_up:
                self.sim.cleanup()

    @property
    def server(self) -> SceneRobotServer:
        return cast(SceneRobotServer, self.robot_servers[0])

    def _due(self) -> list[Fault]:
        """Faults to inject now: the control channel's untimed ones, then those whose robot time
        has come (a timed or scheduled fault waits for a torque-control motion)."""
        due: list[Fault] = []
        if self.channel is not None:
            while True:
                try:
                    fault = self.channel.get_nowait()
                except queue.Empty:
                    break
                (due if fault.at is None else self.pending).append(fault)
        t = self.push.t
        if t is not None and self.pending:
            waiting: list[Fault] = []
            for fault in self.pending:
                (due if fault.at is None or fault.at <= t + TICK / 2 else waiting).append(fault)
            self.pending = waiting
        return due

    def inject(self, fault: Fault) -> None:
        server = self.server
        t = self.push.t
        when = f"robot time {t:.3f} s into the motion" if t is not None else "no motion running"
        self.report(f"fault injected: {fault.spec()} ({when})")
        if fault.kind == "reflex":
            server.inject_reflex(fault.errors)
        elif fault.kind == "user_stop":
            server.inject_user_stop(round(fault.seconds / TICK))
        elif fault.kind == "nan":
            server.nan_field = fault.field
        elif fault.kind == "late":
            self.late_ticks = fault.ticks
        elif fault.kind == "stall":
            time.sleep(fault.seconds)
        elif fault.kind == "drop":
            server.drop()

    def run_once(self, realtime: bool | float = True) -> None:
        start_time = time.time()
        for fault in self._due():
            self.inject(fault)
        for rs in self.robot_servers:
            rs.process_commands()
        steps = max(1, self.late_ticks)
        for step in range(steps):
            if step:  # a tick the client does not hear: no command arrives, the last one holds
                for rs in self.robot_servers:
                    rs._pre_process_commands()
                    rs._post_process_commands()
            self.sim.step()
        if steps > 1:
            # The robot's clock (libfranka's time is the state's message id) runs on unheard.
            self.server._FrankaServer__message_id += steps - 1
            self.late_ticks = 0
        self.server.tick()
        for rs in self.robot_servers:
            rs.send_state()
        remaining = 0.001 * float(realtime) - (time.time() - start_time)
        if remaining > 0:  # a tick already late does not yield the processor (sleep(0) did)
            time.sleep(remaining)


def build_server(
    host: str,
    *,
    task: Task | None = None,
    seed: int = 0,
    person: bool = True,
    faults: Sequence[Fault] = (),
    channel: queue.SimpleQueue[Fault] | None = None,
    report: Report | None = None,
    population: Population | None = None,
) -> SceneServer:
    """The scene server for `task` (None: the bare FR3 at franky-sim's default pose) on `host`, not
    started (use it as a context manager, then ``run_async``/``run_forever``). The arm starts at the
    task's start pose; `person` puts the participant seeded `seed`, drawn from `population` (None:
    phri's default), in the scene."""
    sim = _simulator.MujocoSimulator(enable_visualization=False)
    sim.init()
    if task is None:
        robot = sim.add_robot()
        make_person = None
    else:
        if task.robot != "fr3":
            raise InvalidParameterError(
                f"task: {task.source} is posed for robot '{task.robot}'; the scene server simulates an FR3"
            )
        robot = sim.add_robot(initial_q=tuple(float(v) for v in task.start))
        for body in scene_bodies(task.scene):
            sim.worldbody.append(body)
        model = Robot.fr3()
        make_person = participant_for(task, model, seed, population=population) if person else None
    start = None if task is None else np.asarray(task.start, dtype=float)
    return SceneServer(sim, host, Push(make_person, robot, start), faults, channel, report)


def read_channel(
    stream: TextIO, channel: queue.SimpleQueue[Fault], report: Report, closed: threading.Event | None = None
) -> None:
    """The control channel: one fault per line of `stream` (e.g. ``reflex:joint_velocity_violation``),
    queued for the next tick; a bad line is answered with the reason and ignored. Sets `closed` when
    the stream ends (its writer, e.g. the SimServer's process, is gone)."""
    try:
        for line in stream:
            if not line.strip():
                continue
            try:
                channel.put(Fault.parse(line))
            except InvalidParameterError as e:
                report(f"fault refused: {e}")
    finally:
        if closed is not None:
            closed.set()


def serve(
    host: str,
    *,
    task: Task | None = None,
    realtime: float = 1.0,
    seed: int = 0,
    person: bool = True,
    faults: Sequence[Fault] = (),
    control: TextIO | None = None,
    report: Report | None = None,
    stop: threading.Event | None = None,
    population: Population | None = None,
) -> None:
    """Serves the scene on `host` until interrupted (Ctrl-C), `stop` is set or the control channel
    closes; `realtime` slows the simulation down (2: each 1 ms tick takes 2 ms of wall time). Faults
    come from the schedule `faults` and, one per line, from `control` (the control channel; None:
    none). The participant is drawn from `population` (None: phri's default). A closed control
    channel means its writer is gone (a SimServer's process killed without stopping its server): the
    server stops rather than run on, orphaned."""
    report = report or _log
    channel: queue.SimpleQueue[Fault] = queue.SimpleQueue()
    closed = threading.Event()
    with build_server(
        host, task=task, seed=seed, person=person, faults=faults, channel=channel, report=report,
        population=population,
    ) as server:  # fmt: skip
        if control is not None:
            threading.Thread(
                target=read_channel, args=(control, channel, report, closed), daemon=True
            ).start()
        # The loop first, then the line: a client that connects on it finds the server ticking.
        server.run_async(realtime)
        time.sleep(0.05)
        scene = (
            "the bare FR3"
            if task is None
            else f"task {task.name}"
            + (f", participant seed {seed}" if person else ", no participant")
            + (f" of population {population.source}" if person and population is not None else "")
        )
        report(f"{READY} {host} ({scene}, {realtime:g}x slower than real time); Ctrl-C stops it")
        try:
            while server.async_thread is not None and server.async_thread.is_alive():
                if stop is not None and stop.is_set():
                    break
                if closed.is_set():
                    report("the control channel closed (its writer is gone): stopping")
                    break
                server.async_thread.join(0.2)
        except KeyboardInterrupt:
            pass
