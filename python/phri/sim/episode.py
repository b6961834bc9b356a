"""One simulated attempt at a task: the JACO2 tracks its plan at 1 kHz under the Rust impedance law,
the simulated participant pushes when the cup strays, and the robot either learns (Algorithm 1) or
only complies (the impedance baseline). Scored as the paper's study scored it (Bajcsy et al. 2017,
§4.2: effort, interaction time, task cost).

The robot's side of an episode and its scoring do not depend on PyBullet; an episode on another
backend (a Franka over libfranka, :mod:`phri.franka.episode`) uses the same pieces:
:func:`robot_controls` (the planner, the learner, the impedance law and the safety limits),
:func:`run_on_loop` (the episode on :class:`phri.control.ControlLoop`) and :func:`score_episode`
(the study's measures and the log's arrays).
"""

from __future__ import annotations

import dataclasses
import io
import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from phri import robots
from phri._phri import (
    UPDATE_RULES,
    Deformation,
    Features,
    ImpedanceController,
    InteractionDetector,
    Learner,
    Robot,
    TimedTrajectory,
    TrajectoryOptimizer,
    TrajoptInfo,
    WeightUpdate,
)
from phri._validate import must_be
from phri.atomic import write_atomic
from phri.config import Task
from phri.control import Backend, ControlLoop, LoopResult, RobotState, SafetyLimits, StopEvent, safety_limits
from phri.control.loop import TickHook
from phri.episode_log import geometry_arrays, nearest_rows
from phri.exceptions import InvalidParameterError, PlanningError, SimulationError
from phri.sim.backend import PyBulletBackend, steps_per_period
from phri.sim.native import run_native
from phri.sim.participant import Participant, ParticipantParams
from phri.sim.world import HAND, World, WorldParams

__all__ = [
    "LATER_THRESHOLDS",
    "ORIGINAL_THRESHOLDS",
    "SIMULATORS",
    "STRATEGIES",
    "EpisodeConfig",
    "EpisodeResult",
    "EpisodeTrace",
    "Planner",
    "RobotControls",
    "encode_log",
    "episode_failure",
    "robot_controls",
    "run_episode",
    "run_on_loop",
    "score_episode",
    "simulate_episode",
    "write_log",
]

#: The strategies an episode can use: the impedance baseline (track the plan, spring back) and
#: learning (Algorithm 1).
STRATEGIES = ("impedance", "learning")
#: The simulators an episode can run on: the arm's dynamics and the control loop in Rust
#: (:mod:`phri.sim.native`, the default), or the Python control loop over PyBullet (the reference;
#: docs/simulation.md gives the tolerance between them).
SIMULATORS = ("native", "pybullet")
#: Update rules of phri.WeightUpdate (their one home is the core).
RULES = UPDATE_RULES
#: Plans move each joint at most this fraction of its velocity limit (a margin for tracking).
VELOCITY_MARGIN = 0.5
#: The JACO2's joint count: the length of every per-joint setting below.
JOINTS = 7
#: The study's interaction thresholds, joints 1..7 [N·m] (the detector's default, and the JACO2's
#: ``[interaction]`` thresholds in its robot description).
ORIGINAL_THRESHOLDS = (8.0, 8.0, 8.0, 2.0, 1.0, 1.0, 1.0)
#: The thresholds of the original's later versions, joints 1..7 [N·m] (used there together with a
#: subtracted per-joint bias: EpisodeConfig.detector_bias).
LATER_THRESHOLDS = (4.0, 5.0, 3.0, 4.0, 1.5, 1.5, 1.5)
#: Longest simulated replan latency an episode accepts [s] (EpisodeConfig.replan_latency).
MAX_REPLAN_LATENCY = 1.0
#: Seed plans per learned weight when replans race the wall clock (a real arm; EpisodeConfig.seeds),
#: fewer where that many would pass MAX_SEEDS: a push that moves a weight far starts its
#: replan from a plan made ahead for weights near the new ones (on the study's table task the first
#: push's replan takes about 1-3 ms instead of 35-55 ms, benches/learning.rs).
WALL_CLOCK_SEEDS = 5
#: Most seed plans a learner keeps (the core's; per learned weight to the power of their number).
MAX_SEEDS = Learner.MAX_SEEDS


@dataclass(frozen=True)
class EpisodeConfig:
    """How an episode is run; the defaults are the study's."""

    strategy: str = "learning"
    #: Rate at which the robot samples the person's torque [Hz] (10 in the original, up to 1000).
    sample_rate: float = 10.0
    #: Gaussian noise on the joint-torque measurement, per joint [N·m].
    sensor_noise: float = 0.1
    #: Constant offset on the measurement, per joint [N·m] (None: none); the detector does not know it.
    sensor_bias: tuple[float, ...] | None = None
    #: The interaction detector's per-joint thresholds [N·m] (None: the robot description's
    #: ``[interaction]`` thresholds, else ORIGINAL_THRESHOLDS; the JACO2's are the study's
    #: 8, 8, 8, 2, 1, 1, 1; LATER_THRESHOLDS are the original's later ones).
    thresholds: tuple[float, ...] | None = None
    #: The per-joint bias the detector subtracts from each measurement before thresholding [N·m]
    #: (None: none); set it to sensor_bias for a calibrated sensor.
    detector_bias: tuple[float, ...] | None = None
    #: Update rule: "all" (the paper), "max", "confidence" or "beta" (steps scaled by how well the
    #: learned features explain each push: :func:`phri.rationality`, docs/concepts.md).
    rule: str = "all"
    #: Risk-aware planning: the learner plans with each learned weight raised by this many of the
    #: belief's standard deviations (w + k·σ, clipped to the bounds; :class:`phri.Learner`'s
    #: ``risk``); 0 plans with the estimate, as the paper. Learning episodes only: the impedance
    #: baseline tracks the plan for the initial weights.
    risk: float = 0.0
    #: The simulated person corrects one feature at a time, the most visible first, until it looks
    #: fixed (:class:`~phri.sim.participant.Participant`'s ``one_at_a_time``; HRI 2018). The learner
    #: that matches them is ``rule="max"``, which moves only the weight whose feature changed most.
    one_at_a_time: bool = False
    #: Time-series log rate [Hz].
    log_rate: float = 100.0
    #: After a replan the reference blends into the new plan with joint speeds of at most this
    #: fraction of the velocity limits; 0 switches at once as the original did (the arm then snaps
    #: onto the new plan at several times its limits). A robot description's ``[interaction]
    #: transition_speed`` caps it (the FR3's, whose joints are four times the JACO2's speed).
    transition_speed: float = 0.8
    #: The simulated time a replan takes [s]: the learner replans on its worker thread and adopts
    #: the plan at the first control tick this long after the push's sample, whatever the machine's
    #: load (:class:`phri.Learner`'s ``replan_latency``). One tick of the 1 kHz loop (the default)
    #: gives exactly the results of replanning within the tick (Algorithm 1 as written); 0 replans
    #: inline, in the tick itself.
    replan_latency: float = 0.001
    #: Seed plans per learned weight for the replans (:class:`phri.Learner`'s ``seeds``: each
    #: replan starts from whichever of the current plan and the plans made ahead on a grid of the
    #: weights costs least at the new weights). None: :func:`replan_settings` decides (seeds on a
    #: real arm, whose replans race the wall clock; none in simulation, where they do not).
    seeds: int | None = None
    #: With a replan worker, how long it busy-waits for the next push before it sleeps [s]
    #: (:class:`phri.Learner`'s ``worker_spin``; 0: at once, ``math.inf``: never). On a real arm
    #: spinning saves the worker's wake-up at each push (tens of µs on an idle real-time kernel, up
    #: to milliseconds on a loaded machine) for one CPU core kept busy: only with a core to spare.
    worker_spin: float = 0.0
    #: The deformation gain μ of the learner's intended trajectory, ξ_H = ξ_R + μ·A⁻¹·U_H (paper
    #: eq. 7) [rad per N·m]; None: :class:`phri.Deformation`'s default, the original code's 0.01.
    #: The weight update's first-order step is the task's ``step`` × μ, so scaling μ by s and the
    #: steps by 1/s changes only how far from first order ΔΦ is (docs/participant.md, two features).
    deformation_gain: float | None = None
    #: What simulates the arm and runs the control loop (one of SIMULATORS): "native", the arm's
    #: dynamics and the loop's ticks in Rust (:mod:`phri.sim.native`, many times faster), or
    #: "pybullet", :class:`phri.control.ControlLoop` over PyBullet's JACO2 (the reference, with
    #: contacts and joint limits). Both give the same episode within docs/simulation.md's tolerance.
    simulator: str = "native"

    def __post_init__(self) -> None:
        def fail(key: str, expected: str, got: Any, show: Any = str) -> Exception:
            return must_be(key, expected, got, error=InvalidParameterError, show=show)

        if self.strategy not in STRATEGIES:
            raise fail("strategy", f"one of {STRATEGIES}", self.strategy, repr)
        if not 0 < self.sample_rate <= 1000:
            raise fail("sample_rate", "in (0, 1000] Hz", self.sample_rate)
        if not 0 < self.log_rate <= 1000:
            raise fail("log_rate", "in (0, 1000] Hz", self.log_rate)
        # Against the default simulator rate here; run_episode checks against the world's own.
        steps_per_period("sample_rate", self.sample_rate, WorldParams().timestep)
        steps_per_period("log_rate", self.log_rate, WorldParams().timestep)
        if not (math.isfinite(self.sensor_noise) and self.sensor_noise >= 0):
            raise fail("sensor_noise", "a finite value >= 0 N·m", self.sensor_noise)
        if self.simulator not in SIMULATORS:
            raise fail("simulator", f"one of {SIMULATORS}", self.simulator, repr)
        if self.rule not in RULES:
            raise fail("rule", f"one of {RULES}", self.rule, repr)
        if isinstance(self.risk, bool) or not (
            isinstance(self.risk, int | float) and math.isfinite(self.risk)
        ):
            raise fail("risk", "a finite number of standard deviations", self.risk, repr)
        if not isinstance(self.one_at_a_time, bool):
            raise fail("one_at_a_time", "True or False", self.one_at_a_time, repr)
        if not 0 <= self.transition_speed <= 1:
            raise fail(
                "transition_speed", "a fraction of the velocity limits in [0, 1]", self.transition_speed
            )
        if not (math.isfinite(self.replan_latency) and 0 <= self.replan_latency <= MAX_REPLAN_LATENCY):
            raise fail("replan_latency", f"a time in [0, {MAX_REPLAN_LATENCY:g}] s", self.replan_latency)
        if self.seeds is not None and not (
            isinstance(self.seeds, int)
            and not isinstance(self.seeds, bool)
            and self.seeds != 1
            and self.seeds >= 0
        ):
            raise fail("seeds", "None, 0 (none) or a whole number >= 2", self.seeds, repr)
        spin = self.worker_spin
        if not (isinstance(spin, (int, float)) and not isinstance(spin, bool) and spin >= 0):
            raise fail(
                "worker_spin", "a time >= 0 s (0: the worker sleeps at once; inf: never)", self.worker_spin
            )
        gain = self.deformation_gain
        if gain is not None and not (
            isinstance(gain, (int, float)) and not isinstance(gain, bool) and math.isfinite(gain) and gain > 0
        ):
            raise fail("deformation_gain", "None or a finite gain > 0 rad per N·m", gain, repr)
        for key, positive in (("sensor_bias", False), ("thresholds", True), ("detector_bias", False)):
            value = getattr(self, key)
            if value is not None:
                object.__setattr__(self, key, _per_joint(key, value, positive))


def _per_joint(name: str, value: Sequence[float], positive: bool) -> tuple[float, ...]:
    """`value` as a tuple of JOINTS finite floats (> 0 if `positive`), else an error naming `name`."""
    try:
        v = tuple(float(x) for x in value)
    except (TypeError, ValueError):
        raise InvalidParameterError(
            f"{name} must be {JOINTS} numbers [N·m] (one per joint) or None, got {value!r}"
        ) from None
    if len(v) != JOINTS:
        raise InvalidParameterError(
            f"{name} must have one value per joint ({JOINTS}) [N·m], got {len(v)}: {value!r}"
        )
    for j, x in enumerate(v):
        if not math.isfinite(x) or (positive and x <= 0):
            want = "finite and > 0" if positive else "finite"
            raise InvalidParameterError(f"{name}[{j}] must be {want} [N·m], got {x}")
    return v


@dataclass
class EpisodeResult:
    """Metrics of one episode as the study scored them, and where its log is."""

    task: str
    strategy: str
    #: Σ over interaction samples of Σ_j |u_H,j| [N·m].
    effort: float
    #: Number of interaction samples × sample period [s].
    interaction_time: float
    #: Unweighted task-feature count of the executed path (sampled at the plan's waypoint times).
    cost: float
    #: The same count for the desired behaviour (the plan for the true weights).
    desired_cost: float
    initial_weights: np.ndarray
    final_weights: np.ndarray
    #: Index of the task's own feature in the weights (the one the person teaches).
    task_index: int
    #: Largest distance of the hand from its reference while nobody touches it, at the log rate [m]
    #: (includes the spring-back after a push; see tests for tracking with no participant at all).
    tracking_error: float
    #: Smallest distance of any collision body of the arm (or the cup) to any scene object over
    #: the episode, at the log rate [m]: measured to the collision spheres, which cover the links,
    #: so a lower bound of the true clearance.
    min_clearance: float
    #: Time the virtual wall acted [s] and its largest total force [N] (0: it never acted).
    wall_contact_time: float
    wall_peak_force: float
    wall_time: float
    log: Path | None = None
    frames: list[Path] = field(default_factory=list)
    #: Executed and desired link_7 paths (N, 3) for plots.
    executed_path: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    desired_path: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    #: Every feature's unweighted count of the executed path, sampled as `cost` is (which is its
    #: task feature's), in the task's feature order.
    phi: np.ndarray = field(default_factory=lambda: np.zeros(0))
    #: The episode's log in memory: the arrays a .npz log holds, under the same keys.
    log_arrays: dict[str, np.ndarray] = field(default_factory=dict)
    #: The safety stop that ended the episode early, or None (also in the log: the ``stop_*`` keys).
    stop: StopEvent | None = None

    def row(self) -> dict[str, object]:
        """A flat record for tables."""
        return {
            "task": self.task,
            "strategy": self.strategy,
            "effort": self.effort,
            "interaction_time": self.interaction_time,
            "cost": self.cost,
            "desired_cost": self.desired_cost,
            "final_weight": float(self.final_weights[self.task_index]),
            "tracking_error": self.tracking_error,
            "min_clearance": self.min_clearance,
            "wall_contact_time": self.wall_contact_time,
            "wall_time": self.wall_time,
        }


class Planner:
    """The task's features and optimiser, and the plans for its initial and true weights.

    `world` is the simulator World whose model plans, or the robot's model itself (a real arm's).
    The optimiser keeps every collision body of the arm and the cup at least each scene object's
    margin from it (and from each other) along the executed curve, and each joint within
    VELOCITY_MARGIN of its velocity limit: the safe defaults of TrajectoryOptimizer for a task."""

    def __init__(self, task: Task, world: World | Robot) -> None:
        self.task = task
        model = world if isinstance(world, Robot) else world.model
        self.features = task.feature_set(model)
        model.check_limits(task.start)
        model.check_limits(task.goal)

        def optimizer(features: Features) -> TrajectoryOptimizer:
            return TrajectoryOptimizer(
                features,
                task.waypoints,
                duration=task.duration,
                speed_fraction=VELOCITY_MARGIN,
                knots=task.knots,
            )

        self.optimizer = optimizer(self.features)
        # The person's desired behaviour: the true weights, and the features the robot does not
        # model (Task.unmodelled) at theirs.
        seen = task.seen_by_person()
        person = self.optimizer if seen is task else optimizer(seen.feature_set(model))
        self.desired, info = person.solve(seen.vector("true"), task.start, task.goal)
        self.check(info, "true", person)
        self.desired_cost = float(self.features.phi(self.desired)[task.task_index])

    def check(self, info: TrajoptInfo, weights: str, optimizer: TrajectoryOptimizer | None = None) -> None:
        """Raises PlanningError, naming the task file, the cause and the violated pair, unless the
        plan just made (for the task's `weights` weights, by `optimizer`, default the robot's) is
        feasible and converged."""
        task = self.task
        if info.max_violation > TrajectoryOptimizer.CLEARANCE_TOLERANCE:
            pair = (optimizer or self.optimizer).closest_pair
            what = (
                f"'{pair[0]}' comes within {pair[2]:.3f} m of '{pair[1]}' (margin {pair[3]:.3f} m)"
                if pair is not None
                else f"a margin is violated by {info.max_violation:.3f} m"
            )
            raise PlanningError(
                f"{task.source}: the plan for the {weights} weights cannot keep the arm clear: {what}; "
                f"check start, goal and [scene]"
            )
        if not info.feasible:
            raise PlanningError(
                f"{task.source}: the goal is too far from the start for duration = {task.duration:g} s: "
                f"the plan for the {weights} weights moves a joint {info.max_step_excess:.3f} rad per "
                f"segment faster than {VELOCITY_MARGIN:g} × its velocity limit allows; make the task "
                f"last longer or move the goal"
            )
        if not info.converged:
            raise PlanningError(
                f"{task.source}: the plan for the {weights} weights did not converge "
                f"({info.iterations} iterations, cost {info.cost:.6g})"
            )


def encode_log(arrays: Mapping[str, np.ndarray]) -> bytes:
    """An episode log as the bytes of a compressed .npz, made in memory (a pool worker hands these to
    the process that owns the output folder, which writes them once)."""
    buffer = io.BytesIO()
    np.savez_compressed(buffer, **arrays)  # type: ignore[arg-type]
    return buffer.getvalue()


def write_log(path: Path, arrays: Mapping[str, np.ndarray]) -> Path:
    """Writes an episode log (compressed .npz) atomically; an existing `path` is a FileExistsError:
    a log, once written, is never overwritten."""
    return write_atomic(path, encode_log(arrays), overwrite=False)


@dataclass
class RobotControls:
    """The robot's side of an episode, the same in simulation and on a real arm: the task's planner,
    the learner (Algorithm 1, or only compliance for the impedance strategy), the impedance law
    with the task's scene (the run-time clearance wall) and the safety layer's limits, and the
    interaction detector's thresholds [N·m] per joint."""

    planner: Planner
    learner: Learner
    controller: ImpedanceController
    limits: SafetyLimits
    thresholds: tuple[float, ...]


def make_learner(
    task: Task,
    planner: Planner,
    config: EpisodeConfig,
    thresholds: Sequence[float],
    *,
    replan_latency: float | None,
    optimizer: TrajectoryOptimizer | None = None,
) -> Learner:
    """The episode's learner: the one place an episode's :class:`phri.Learner` is made.

    `replan_latency` [s]: a simulated episode's is ``config.replan_latency`` (0 replans inline, a
    positive time adopts the worker's plan that long after the push's sample, deterministically);
    None adopts it at the first tick after it is ready (a real arm's), see :class:`phri.Learner`.
    `optimizer`: the replans' optimiser (default: the planner's). Seed plans and the worker's spin:
    :func:`replan_settings`."""
    seeds, worker_spin = replan_settings(task, config, replan_latency)
    learning = config.strategy == "learning"
    update = WeightUpdate(
        task.vector("step"), task.vector("lower"), task.vector("upper"),
        learned=[f.learned for f in task.features], rule=config.rule,  # type: ignore[arg-type]
    )  # fmt: skip
    detector = InteractionDetector(
        list(thresholds), None if config.detector_bias is None else config.detector_bias
    )
    deformation = (
        Deformation() if config.deformation_gain is None else Deformation(mu=config.deformation_gain)
    )
    return Learner(
        planner.features, deformation, update, detector, optimizer or planner.optimizer,
        task.vector("initial"), task.start, task.goal,
        duration=task.duration, sample_period=1.0 / config.sample_rate,
        learning=learning, transition_speed=config.transition_speed,
        replan_latency=replan_latency, seeds=seeds, worker_spin=worker_spin,
        # Risk is the learning robot's: the impedance baseline tracks the plan for the initial weights.
        risk=[config.risk if f.learned else 0.0 for f in task.features] if config.risk and learning else None,
    )  # fmt: skip


def replan_settings(task: Task, config: EpisodeConfig, replan_latency: float | None) -> tuple[int, float]:
    """The learner's seed plans per learned weight and its worker's spin [s] for an episode of `task`
    (see :func:`make_learner`): ``config``'s; by default WALL_CLOCK_SEEDS when a learning episode
    replans on the wall clock and every learned weight has finite bounds (fewer if that many would
    pass MAX_SEEDS), else none. An impedance episode never replans: no seeds, no spin."""
    if config.strategy != "learning":
        return 0, 0.0
    if config.seeds is not None:
        return config.seeds, config.worker_spin
    learned = [f for f in task.features if f.learned]
    bounded = all(math.isfinite(f.lower) and math.isfinite(f.upper) for f in learned)
    seeds = WALL_CLOCK_SEEDS if replan_latency is None and learned and bounded else 0
    while seeds >= 2 and seeds ** len(learned) > MAX_SEEDS:
        seeds -= 1
    return (seeds if seeds >= 2 else 0), config.worker_spin


def robot_controls(
    task: Task,
    model: Robot,
    config: EpisodeConfig,
    planner: Planner | None = None,
    *,
    replan_latency: float | None,
) -> RobotControls:
    """The robot's side of an episode of `task` on `model` (`task.robot`'s description supplies the
    interaction thresholds, the cap on the blend's speed, the impedance gains and the safety limits):
    the planner (made here if `planner` is None), the learner (:func:`make_learner` with
    `replan_latency`; its blend into a new plan no faster than the description's
    ``transition_speed``), the impedance law with the task's scene
    (:func:`phri.robots.impedance_controller`) and the safety limits (the robot's ``[safety]``
    tightened by the task's)."""
    for key in ("thresholds", "detector_bias"):
        value = getattr(config, key)
        if value is not None and len(value) != model.nq:
            raise InvalidParameterError(f"{key} must have one value per joint ({model.nq}), got {len(value)}")
    description = robots.load(task.robot)
    planner = planner or Planner(task, model)
    thresholds = config.thresholds or description.thresholds or ORIGINAL_THRESHOLDS
    if len(thresholds) != model.nq:
        raise InvalidParameterError(
            f"{description.source}: key 'interaction.thresholds' must have one value per joint "
            f"({model.nq}), got {len(thresholds)}"
        )
    cap = description.transition_speed
    if cap is not None and config.transition_speed > cap:
        config = dataclasses.replace(config, transition_speed=cap)
    learner = make_learner(task, planner, config, thresholds, replan_latency=replan_latency)
    # The virtual wall keeps every body clear of the furniture at run time, however the person pushes.
    controller = robots.impedance_controller(model, description, task.scene)
    # The safety layer's limits: the robot's [safety] table, tightened by the task's, its tool box.
    limits = safety_limits(model, description, task)
    return RobotControls(planner, learner, controller, limits, tuple(float(x) for x in thresholds))


@dataclass
class _Parts:
    """What one simulated episode runs: the robot's side (the planner, the learner, the controller
    and its safety limits), the person and the sensor, and the simulator steps between two torque
    samples and two log rows."""

    planner: Planner
    learner: Learner
    controller: ImpedanceController
    limits: SafetyLimits
    person: Participant
    sensor_rng: np.random.Generator
    #: The sensor's constant offset, per joint [N·m].
    bias: np.ndarray
    sample_every: int
    log_every: int


def _set_up(
    task: Task,
    world: World,
    participant_params: ParticipantParams,
    config: EpisodeConfig,
    seed: int,
    planner: Planner | None,
) -> _Parts:
    """Checks `config` against the world and builds the episode's learner, controller and person
    (and the task's planner if `planner` is None)."""
    dt = world.params.timestep
    sample_every = steps_per_period("sample_rate", config.sample_rate, dt)
    log_every = steps_per_period("log_rate", config.log_rate, dt)
    model = world.model
    if config.sensor_bias is not None and len(config.sensor_bias) != model.nq:
        raise InvalidParameterError(
            f"sensor_bias must have one value per joint ({model.nq}), got {len(config.sensor_bias)}"
        )
    # Independent streams for the person and the sensor: the same seed gives the same person (their
    # own draws) whatever the sensor does, e.g. under both strategies or another sensor_noise.
    person_rng, sensor_rng = (np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(2))
    controls = robot_controls(
        task, model, config, planner or Planner(task, world), replan_latency=config.replan_latency
    )
    planner = controls.planner
    desired = TimedTrajectory(planner.desired, task.duration)
    person = Participant(
        participant_params, task, model, desired, person_rng, dt=dt, one_at_a_time=config.one_at_a_time
    )
    bias = np.zeros(model.nq) if config.sensor_bias is None else np.asarray(config.sensor_bias, dtype=float)
    return _Parts(
        planner, controls.learner, controls.controller, controls.limits, person, sensor_rng, bias,
        sample_every, log_every,
    )  # fmt: skip


@dataclass
class EpisodeTrace:
    """The control loop's record of an episode at the log rate: the first `rows` rows of each
    array are filled."""

    t: np.ndarray
    #: q, qd, q_ref, tau, u_h (measured) per joint, push (the person's wrench at the hand: force
    #: [N], torque [N·m]; zero while nobody touches it) and wall_force [N].
    series: dict[str, np.ndarray]
    rows: int = 0
    #: Largest hand-to-reference distance while nobody touches the hand [m].
    tracking_error: float = 0.0
    #: Control ticks at which the virtual wall acted, and its largest total force [N].
    wall_ticks: int = 0
    wall_peak_force: float = 0.0
    frames: list[Path] = field(default_factory=list)
    #: The control loop's result (its stop, the safety layer's clip counts).
    loop: LoopResult = field(default_factory=LoopResult)
    #: What stopped the loop early (None: it ran to the end of the task): a safety stop
    #: (SafetyStopError) or any other error, kept with the log so far.
    error: BaseException | None = None


#: The person's wrench at the hand (force [N], torque [N·m]) for a state, None while nobody touches
#: the hand.
PushOf = Callable[[RobotState], "np.ndarray | None"]


def run_on_loop(
    task: Task,
    backend: Backend,
    learner: Learner,
    controller: ImpedanceController,
    limits: SafetyLimits,
    push_of: PushOf,
    *,
    log_rate: float,
    hand: str,
    on_tick: TickHook | None = None,
    implicit: bool = True,
) -> EpisodeTrace:
    """The episode of `task` on :class:`phri.control.ControlLoop` over `backend`: the learner
    updates its reference from the measured torque, the impedance law tracks it and the safety
    layer watches, for ``task.duration`` seconds of the robot's time from ``task.start``.

    At each log row `push_of(state)` gives the person's wrench at the hand (logged as ``push``);
    while it is None the hand's distance from its reference (frame `hand`) counts towards the
    tracking error. `on_tick` is the loop's tick hook, called after this one. `implicit`: the
    loop's impedance law (:class:`phri.control.ControlLoop`; False on a real arm). A safety stop or
    an error ends the episode and is kept in the trace, with the log so far."""
    model = backend.robot
    tracking = {"error": 0.0}

    def hook(k: int, state: RobotState, row: int) -> None:
        if row >= 0:
            push = push_of(state)
            if push is not None:
                push_rows[row] = push
            else:  # the hand's distance from its reference while nobody touches it
                gap = model.frame_pose(hand, state.q)[:3, 3] - model.frame_pose(hand, loop.q_ref)[:3, 3]
                tracking["error"] = max(tracking["error"], float(np.linalg.norm(gap)))
        if on_tick is not None:
            on_tick(k, state, row)

    loop = ControlLoop(
        backend, learner, controller, limits, log_rate=log_rate, on_tick=hook, implicit=implicit
    )
    #: The person's wrench at the hand (force [N], torque [N·m]) at each log row; zero while nobody
    #: touches it. As many rows as the loop's log can hold (the task, and a stop's hold).
    push_rows = np.zeros((int((task.duration + loop.hold_time) / loop.log_period) + 4, 6))
    error: BaseException | None = None
    try:
        result = loop.run(task.start, task.duration, check=False)
        error = result.error
    except BaseException as e:  # noqa: BLE001 - kept with the log so far; the caller re-raises it
        error, result = e, loop.result
    log = result.log
    n = len(log["t"])
    series = {key: log[key] for key in ("q", "qd", "q_ref", "tau")}
    series["u_h"] = log["tau_ext"]
    series["push"] = push_rows[:n]
    #: The virtual wall's largest total force since the previous row [N] (0: it did not act).
    series["wall_force"] = log["wall_force"]
    return EpisodeTrace(
        log["t"], series, rows=n, tracking_error=tracking["error"], wall_ticks=result.wall_ticks,
        wall_peak_force=result.wall_peak_force, loop=result, error=error,
    )  # fmt: skip


def _simulate(
    task: Task,
    world: World,
    parts: _Parts,
    config: EpisodeConfig,
    frame_times: Sequence[float],
    frame_prefix: Path | None,
) -> EpisodeTrace:
    """The episode on ``config.simulator``: the person pushes, the sensor samples, the learner
    updates its reference, the impedance controller tracks it and the safety layer watches."""
    dt = world.params.timestep
    world.set_scene(task.scene)
    frame_ticks = {int(round(ft / dt)): ft for ft in frame_times}
    frames: list[Path] = []

    def render(k: int) -> None:
        frames.append(world.render(f"{frame_prefix}_t{frame_ticks[k]:05.2f}.png"))

    if config.simulator == "native":
        trace = _simulate_native(task, world, parts, config, frame_ticks if frame_prefix else {}, render)
        trace.frames = frames
        return trace
    backend = PyBulletBackend(
        world, participant=parts.person, sample_rate=config.sample_rate,
        sensor_noise=config.sensor_noise, sensor_bias=parts.bias, rng=parts.sensor_rng,
    )  # fmt: skip

    def push_of(state: RobotState) -> np.ndarray | None:
        push = backend.push
        return None if push is None else np.concatenate(push)

    def on_tick(k: int, state: RobotState, row: int) -> None:
        if frame_prefix is not None and k in frame_ticks:
            render(k)

    trace = run_on_loop(
        task, backend, parts.learner, parts.controller, parts.limits, push_of,
        log_rate=config.log_rate, hand=HAND, on_tick=on_tick,
    )  # fmt: skip
    trace.frames = frames
    return trace


def _simulate_native(
    task: Task,
    world: World,
    parts: _Parts,
    config: EpisodeConfig,
    frame_ticks: Mapping[int, float],
    render: Callable[[int], None],
) -> EpisodeTrace:
    """The episode on :func:`phri.sim.native.run_native`; a frame is rendered by placing the
    PyBullet arm at the tick's joint positions."""

    def on_frame(k: int, q: np.ndarray) -> None:
        world.reset(q)
        render(k)

    run = run_native(
        world, task.start, task.duration, parts.learner, parts.controller, parts.limits, parts.person,
        sample_every=parts.sample_every, sensor_noise=config.sensor_noise, bias=parts.bias,
        rng=parts.sensor_rng, log_rate=config.log_rate, frame_ticks=list(frame_ticks), on_frame=on_frame,
    )  # fmt: skip
    log = run.loop.log
    n = len(log["t"])
    series = {key: log[key] for key in ("q", "qd", "q_ref", "tau")}
    series["u_h"] = log["tau_ext"]
    series["push"] = run.push
    series["wall_force"] = log["wall_force"]
    # The hand's distance from its reference while nobody touches it (as run_on_loop measures it).
    free = ~run.touched
    tracking = 0.0
    if free.any():
        hand = world.model.frame_pose(HAND, log["q"][free])[:, :3, 3]
        wanted = world.model.frame_pose(HAND, log["q_ref"][free])[:, :3, 3]
        tracking = float(np.linalg.norm(hand - wanted, axis=1).max())
    return EpisodeTrace(
        log["t"], series, rows=n, tracking_error=tracking, wall_ticks=run.loop.wall_ticks,
        wall_peak_force=run.loop.wall_peak_force, loop=run.loop,
        error=run.error if run.error is not None else run.loop.error,
    )  # fmt: skip


def _history(learner: Learner, initial_weights: np.ndarray) -> dict[str, np.ndarray]:
    """The learner's history as log arrays: each interaction sample's time [s], measured torque
    [N·m] and feature change ΔΦ = Φ(ξ_H) − Φ(ξ_R) (the update's input; NaN where no deformation
    was made: under impedance, or past the deformation's last window), the weights after each (from
    t = 0, the initial weights), each push's rationality β̂ and explained fraction and the belief's
    covariance after it (NaN where no deformation was made), and each replan's time and plan."""
    history = learner.history()
    return {
        "interaction_t": history.t,
        "interaction_u_h": history.u_h,
        "interaction_delta_phi": history.delta_phi,
        "interaction_beta": history.beta,
        "interaction_explained": history.explained,
        "belief_covariance": history.covariance,
        "weights_t": np.concatenate([[0.0], history.t]),
        "weights": np.vstack([initial_weights, history.weights]),
        "plan_t": history.plan_t,
        "plans": history.plans,
        "rejected_t": history.rejected_t,
        "rejected": np.array(history.rejected, dtype=str),
    }


def score_episode(
    task: Task,
    model: Robot,
    planner: Planner,
    learner: Learner,
    trace: EpisodeTrace,
    config: EpisodeConfig,
    initial_weights: np.ndarray,
    *,
    period: float,
) -> EpisodeResult:
    """The study's measures of the episode `trace` of `task` on `model` (control period `period`
    [s]), with its log arrays (the keys of the .npz log); wall_time is left for the caller."""
    history = _history(learner, initial_weights)
    # The executed path at the plan's waypoint times (the log rows nearest to them: the rows are on
    # the log's time grid but for a tick the robot missed), scored with the same features.
    idx = nearest_rows(trace.t[: trace.rows], np.linspace(0, task.duration, task.waypoints))
    executed = trace.series["q"][idx]
    phi = planner.features.phi(executed)
    frame = planner.features.frame
    rows = trace.rows
    stop = trace.loop.stop
    # Each collision body's smallest distance to each scene object at every log row [m].
    distances = model.scene_distances(trace.series["q"][:rows], task.scene)
    return EpisodeResult(
        task=task.name,
        strategy=config.strategy,
        effort=float(np.abs(history["interaction_u_h"]).sum()),
        interaction_time=len(history["interaction_t"]) / config.sample_rate,
        cost=float(phi[task.task_index]),
        desired_cost=planner.desired_cost,
        initial_weights=initial_weights,
        final_weights=learner.weights,
        task_index=task.task_index,
        tracking_error=trace.tracking_error,
        min_clearance=float(distances.min()) if distances.size else math.inf,
        wall_contact_time=trace.wall_ticks * period,
        wall_peak_force=trace.wall_peak_force,
        wall_time=0.0,
        executed_path=model.frame_pose(frame, executed)[:, :3, 3],
        desired_path=model.frame_pose(frame, planner.desired)[:, :3, 3],
        phi=phi,
        frames=trace.frames,
        log_arrays={
            "t": trace.t[:rows], **{k: v[:rows] for k, v in trace.series.items()}, **history,
            "desired": planner.desired, "feature_names": np.array(task.feature_names),
            # φ per segment of the executed path (at the waypoint times) and of the desired one.
            "segment_phi": planner.features.per_segment(executed),
            "desired_segment_phi": planner.features.per_segment(planner.desired),
            "distances": distances, "body_names": np.array(model.collision_bodies),
            "object_names": np.array(task.scene.names),
            # What a replay needs besides the series: the robot's spheres and the scene's objects.
            **geometry_arrays(
                model, task.scene, robot=task.robot, task=task.name, strategy=config.strategy, frame=frame
            ),
            # The safety layer: ticks whose torque (or command rate) it clipped, per joint, and the
            # stop that ended the episode (no row without one).
            "torque_clips": trace.loop.torque_clips, "rate_clips": trace.loop.rate_clips,
            **(StopEvent.empty_arrays(model.nq) if stop is None else stop.arrays()),
        },
        stop=stop,
    )  # fmt: skip


def simulate_episode(
    task: Task,
    world: World,
    participant_params: ParticipantParams,
    config: EpisodeConfig | None = None,
    *,
    seed: int = 0,
    planner: Planner | None = None,
    frame_times: Sequence[float] = (),
    frame_prefix: Path | None = None,
) -> tuple[EpisodeResult, BaseException | None]:
    """Simulates one attempt at `task` as :func:`run_episode` does, writing no log: returns the result
    (its `log_arrays` hold the log, in memory) and the error that stopped the simulation early (None
    if it ran to the end; the result then covers the time simulated, and for a safety stop, a
    :class:`~phri.exceptions.SafetyStopError`, the hold after it). Set-up errors are raised."""
    config = config or EpisodeConfig()
    for i, ft in enumerate(frame_times):
        if isinstance(ft, bool) or not isinstance(ft, int | float) or not 0 <= ft <= task.duration:
            raise InvalidParameterError(
                f"frame_times[{i}] must be a time in [0, {task.duration:g}] s, got {ft!r}"
            )
    began = time.perf_counter()
    parts = _set_up(task, world, participant_params, config, seed, planner)
    initial_weights = parts.learner.weights
    trace = _simulate(task, world, parts, config, frame_times, frame_prefix)
    result = score_episode(
        task, world.model, parts.planner, parts.learner, trace, config, initial_weights,
        period=world.params.timestep,
    )  # fmt: skip
    result.wall_time = time.perf_counter() - began
    return result, trace.error


def episode_failure(task: str, strategy: str, error: Exception, log: object) -> SimulationError:
    """The error of an episode the simulator failed (or the safety layer stopped): names the task,
    the strategy and the log so far."""
    return SimulationError(f"{task}/{strategy}: {error} (log so far: {log})")


def run_episode(
    task: Task,
    world: World,
    participant_params: ParticipantParams,
    config: EpisodeConfig | None = None,
    *,
    seed: int = 0,
    planner: Planner | None = None,
    log_path: Path | None = None,
    frame_times: Sequence[float] = (),
    frame_prefix: Path | None = None,
) -> EpisodeResult:
    """Simulates one attempt at `task` for `task.duration` seconds at the world's time step.

    The episode runs on :class:`phri.control.ControlLoop` over the PyBullet JACO2
    (:class:`phri.sim.backend.PyBulletBackend`), whose safety layer takes its limits from the robot
    description and the task (``[safety]``). `log_path` (.npz) receives the compressed time series
    (also when the simulation fails or the safety layer stops the arm: the log so far, its stop in the
    ``stop_*`` arrays, then the error is raised); `frame_times` [s] are rendered to
    ``{frame_prefix}_t{t:05.2f}.png`` with PyBullet's software renderer."""
    config = config or EpisodeConfig()
    result, error = simulate_episode(
        task, world, participant_params, config, seed=seed, planner=planner,
        frame_times=frame_times, frame_prefix=frame_prefix,
    )  # fmt: skip
    if log_path is not None:
        result.log = write_log(Path(log_path), result.log_arrays)
    if isinstance(error, SimulationError):
        raise episode_failure(task.name, config.strategy, error, result.log) from error
    if error is not None:
        raise error
    return result
