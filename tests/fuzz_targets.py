"""The public entry points of phri as fuzz targets, and a runner that fuzzes one of them with
Hypothesis: ``python tests/fuzz_targets.py TARGET EXAMPLES``. tests/test_fuzz.py runs each target in
a child process of its own with a memory and time limit, so that an abort, a segfault or a hang is
a failing test that names the target and the call, not a dead test run.

Every call must either return a finite result (every float in it finite) or raise a typed error
about an argument it was given: a phri error whose message names one of the call's arguments, or a
TypeError that names it (PyO3's "argument 'q': ..."). A PlanningError or NotConvergedError is a
typed outcome about the problem as a whole and needs no argument's name. Anything else fails: a
PanicException, a bare ValueError or OverflowError, a NaN in the result.

Inputs are drawn around what each argument expects: arrays of the right shape and of wrong ones,
every numpy dtype kind, C, Fortran and strided layouts, lists, NaN, ±inf, ±1e308, subnormals; and
for integers huge and negative values and other types.
"""

from __future__ import annotations

import math
import os
import shutil
import sys
import tempfile
from collections.abc import Callable
from dataclasses import dataclass, field
from importlib.resources import files
from pathlib import Path
from typing import Any

import numpy as np
from fake_arm import FakeArm
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import phri
from phri.control import ControlLoop, SafetyLayer, safety_limits
from phri.exceptions import NotConvergedError, PhriError, PlanningError
from phri.robots import impedance_controller
from phri.robots import load as load_description
from phri.sim.participant import Participant, ParticipantParams, load_population

# -- what arguments are drawn from ----------------------------------------------------------------

SPECIAL = [
    0.0,
    -0.0,
    1.0,
    -1.0,
    5e-324,
    1e-300,
    1e-12,
    1e12,
    1e300,
    1.7e308,
    -1.7e308,
    math.nan,
    math.inf,
    -math.inf,
]
WRONG_TYPES = st.sampled_from([None, "x", "1.5", b"1", True, 1 + 2j, object(), [1.0, "a"], {}])
HUGE_INTS = [-1, -(2**31), -(2**70), 0, 1, 2, 2**31, 2**63 - 1, 2**63, 2**64, 2**70, 10**30]


def reals(lo: float = -10.0, hi: float = 10.0) -> st.SearchStrategy[float]:
    """Mostly in [lo, hi], sometimes a special value."""
    return st.one_of(
        st.floats(lo, hi, allow_nan=False), st.floats(lo, hi, allow_nan=False), st.sampled_from(SPECIAL)
    )


def scalars(lo: float = -10.0, hi: float = 10.0) -> st.SearchStrategy[Any]:
    """A float argument: a real, an int, a numpy scalar, or a value of another type."""
    return st.one_of(
        reals(lo, hi),
        reals(lo, hi),
        reals(lo, hi).map(np.float64),
        st.integers(-3, 3),
        st.sampled_from(HUGE_INTS),
        WRONG_TYPES,
    )


def ints(lo: int, hi: int) -> st.SearchStrategy[Any]:
    """An integer argument: valid ones, the edges, huge and negative ones, numpy integers, others."""
    return st.one_of(
        st.integers(lo, hi),
        st.integers(lo, hi),
        st.sampled_from(HUGE_INTS),
        st.integers(lo, hi).map(np.int64),
        st.sampled_from([1.5, True, "3", None, np.uint8(3)]),
    )


def names(known: list[str]) -> st.SearchStrategy[Any]:
    return st.one_of(
        st.sampled_from(known),
        st.sampled_from(known),
        st.sampled_from(["", "nope", "\x00", "../x", "é" * 300]),
        st.text(max_size=8),
        WRONG_TYPES,
    )


@st.composite
def arrays(draw: st.DrawFn, shape: tuple[int | None, ...], lo: float = -3.0, hi: float = 3.0) -> Any:
    """Mostly an array of `shape` (None: any length 0-40), else a wrong shape; then one of the dtypes
    and layouts (or a list, a masked array, a scalar)."""
    dims = [d if d is not None else draw(st.integers(2, 40)) for d in shape]
    if draw(st.integers(0, 5)) == 0:  # a wrong shape
        dims = draw(
            st.one_of(
                st.just(dims[:-1]),
                st.just([*dims, 2]),
                st.just([*dims[:-1], dims[-1] + 1] if dims else [1]),
                st.just([0, *dims[1:]]),
                st.lists(st.integers(0, 9), max_size=3),
            )
        )
    size = int(np.prod(dims)) if dims else 1
    base = draw(st.sampled_from(["uniform", "uniform", "uniform", "special"]))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    values = rng.uniform(lo, hi, size)
    if base == "special" and size:
        k = draw(st.integers(1, max(1, min(size, 3))))
        for _ in range(k):
            values[draw(st.integers(0, size - 1))] = draw(st.sampled_from(SPECIAL))
    a = values.reshape(dims)
    form = draw(
        st.sampled_from(
            [
                "c",
                "c",
                "c",
                "list",
                "fortran",
                "strided",
                "float32",
                "int",
                "uint8",
                "bool",
                "complex",
                "str",
                "masked",
                "object",
                "datetime",
                "structured",
                "scalar",
                "none",
            ]  # fmt: skip
        )
    )
    match form:
        case "c":
            return a
        case "list":
            return a.tolist()
        case "fortran":
            return np.asfortranarray(a)
        case "strided":
            wide = np.repeat(a[..., None], 2, axis=-1)
            return wide[..., 0]
        case "float32":
            with np.errstate(over="ignore"):
                return a.astype(np.float32)
        case "int":
            return np.nan_to_num(a, posinf=0, neginf=0).clip(-1e9, 1e9).astype(np.int64)
        case "uint8":
            return np.nan_to_num(a).clip(0, 255).astype(np.uint8)
        case "bool":
            return a > 0
        case "complex":
            return a + 1j
        case "str":
            return a.astype(str)
        case "masked":
            return np.ma.masked_array(a, mask=a > 0)
        case "object":
            return a.astype(object)
        case "datetime":
            return np.zeros(a.shape, "datetime64[s]")
        case "structured":
            return np.zeros(a.shape, [("x", float)])
        case "scalar":
            return float(values[0]) if size else 0.0
        case _:
            return None


# -- the targets ----------------------------------------------------------------------------------


@dataclass
class Target:
    """`call(obj, **kwargs)` on the object `setup()` makes, with each argument from `args`."""

    setup: Callable[[], Any]
    call: Callable[..., Any]
    args: dict[str, st.SearchStrategy[Any]]
    #: Fraction of the default number of examples (slow calls get fewer).
    weight: float = 1.0
    extra: dict[str, Any] = field(default_factory=dict)


def _robot() -> phri.Robot:
    return phri.Robot.jaco2()


JACO2 = _robot()
N = JACO2.nq
FRAMES = JACO2.frame_names
Q_MID = (JACO2.lower_limits.clip(-3, 3) + JACO2.upper_limits.clip(-3, 3)) / 2
TABLE = phri.SceneObject("table", "box", [0.4, 0.0, -0.1], size=[1.0, 1.4, 0.04], kind="furniture")
LAPTOP = phri.SceneObject("laptop", "box", [0.5, 0.3, 0.0], size=[0.3, 0.25, 0.02])


def _features() -> phri.Features:
    return phri.Features(JACO2, ["efficiency", "table", "coffee", "origin"])


def _optimizer() -> phri.TrajectoryOptimizer:
    return phri.TrajectoryOptimizer(_features(), 11, speed_limits=False, collisions=False, max_iterations=20)


def _levels() -> tuple[phri.TrajectoryOptimizer, phri.PlanLevels]:
    o = _optimizer()
    levels, _ = o.solve_levels([1, 1, 1, 1], Q_MID, Q_MID + 0.1)
    return o, levels


def _learner_parts() -> dict[str, Any]:
    f = phri.Features(JACO2, ["efficiency", "table"])
    return {
        "features": f,
        "deformation": phri.Deformation(),
        "update": phri.WeightUpdate([0.0, 1.0], [0.0, -10.0], [10.0, 10.0]),
        "detector": phri.InteractionDetector(),
        "optimizer": phri.TrajectoryOptimizer(f, 11, duration=8.0, collisions=False, max_iterations=20),
    }


def _learner() -> phri.Learner:
    p = _learner_parts()
    return phri.Learner(**p, weights=[1.0, 1.0], start=Q_MID, goal=Q_MID + 0.1, duration=8.0)


def _urdf_text() -> str:
    return (files("phri") / "robots" / "jaco2" / "j2s7s300.urdf").read_text()


def _urdf_variants() -> st.SearchStrategy[Any]:
    text = _urdf_text()
    return st.one_of(
        st.just(text),
        st.integers(0, len(text)).map(lambda k: text[:k]),  # truncated
        st.tuples(st.integers(0, len(text)), st.text(max_size=20)).map(
            lambda p: text[: p[0]] + p[1] + text[p[0] :]
        ),
        st.sampled_from(
            [
                "",
                "<robot/>",
                '<robot name="r"><link name="a"/></robot>',
                "<x>" * 200 + "</x>" * 200,
                "\x00",
                "<?xml",
            ]
        ),
        WRONG_TYPES,
    )


def _path_variants() -> st.SearchStrategy[Any]:
    tmp = Path(tempfile.mkdtemp(prefix="phri-fuzz-"))
    (tmp / "empty.urdf").write_text("")
    (tmp / "bad.urdf").write_bytes(b"\xff\xfe<robot")
    return st.one_of(
        st.sampled_from(
            [
                str(tmp / "empty.urdf"),
                str(tmp / "bad.urdf"),
                str(tmp),
                str(tmp / "missing.urdf"),
                "",
                "/dev/null",
            ]
        ),
        st.just(files("phri") / "robots" / "jaco2" / "j2s7s300.urdf"),
        WRONG_TYPES,
    )


def _use_trajectory(*, times: Any, t: Any, waypoints: Any, speed_limits: Any) -> Any:
    tr = phri.TimedTrajectory(np.linspace(Q_MID, Q_MID + 0.5, 11), 5.0)
    return (
        tr.sample_many(times),
        tr.index_at(t),
        tr.switch_to(waypoints, t, speed_limits),
        tr.sample_many(times),
        tr.sample(t),
        tr.sample_plan(t=t),
    )


TRAJ = arrays((None, N), -2.0, 2.0)
VEC = arrays((N,))
BATCH = st.one_of(arrays((N,)), arrays((None, N)))

TARGETS: dict[str, Target] = {
    # Robot
    "Robot.from_urdf_string": Target(
        lambda: None,
        lambda _, **kw: phri.Robot.from_urdf_string(**kw),
        {
            "urdf": _urdf_variants(),
            "base": st.one_of(st.none(), names(FRAMES)),
            "tip": st.one_of(st.none(), names(FRAMES)),
        },
    ),
    "Robot.from_urdf": Target(
        lambda: None, lambda _, **kw: phri.Robot.from_urdf(**kw), {"path": _path_variants()}
    ),
    "Robot.kinematics": Target(
        _robot,
        lambda r, *, method, **kw: getattr(r, method)(**kw),
        {"method": st.sampled_from(["frame_pose", "jacobian"]), "frame": names(FRAMES), "q": BATCH},
    ),
    "Robot.dynamics": Target(
        _robot,
        lambda r, **kw: (
            r.gravity(kw["q"]),
            r.mass_matrix(q=kw["q"]),
            r.inverse_dynamics(**kw),
            r.nonlinear_effects(kw["q"], kw["qd"]),
        ),
        {"q": BATCH, "qd": BATCH, "qdd": BATCH},
    ),
    "Robot.check_limits": Target(_robot, lambda r, **kw: r.check_limits(**kw), {"q": VEC}),
    "Robot.with_payload": Target(
        _robot,
        lambda r, **kw: r.with_payload(**kw).gravity(Q_MID),
        {
            "frame": names(FRAMES),
            "mass": scalars(0, 5),
            "com": st.one_of(st.none(), arrays((3,))),
            "inertia": st.one_of(st.none(), arrays((3, 3))),
        },
    ),
    "Robot.with_collision_spheres": Target(
        _robot,
        lambda r, **kw: r.with_collision_spheres(**kw).scene_distances(Q_MID, phri.Scene([TABLE])),
        {
            "name": names(["cup", "link_2"]),
            "frame": names(FRAMES),
            "centers": arrays((None, 3), -0.2, 0.2),
            "radii": arrays((None,), 0.0, 0.1),
        },
    ),
    "Robot.scene_distances": Target(
        _robot, lambda r, **kw: r.scene_distances(scene=phri.Scene([TABLE, LAPTOP]), **kw), {"q": BATCH}
    ),
    # Scene
    "SceneObject": Target(
        lambda: None,
        lambda _, **kw: phri.Scene([phri.SceneObject(**kw)]).objects[0].pose,
        {
            "name": names(["table", "laptop"]),
            "shape": names(["box", "cylinder", "sphere", "plane"]),
            "position": arrays((3,)),
            "size": st.one_of(st.none(), arrays((3,), 0, 1)),
            "radius": st.one_of(st.none(), scalars(0, 1)),
            "length": st.one_of(st.none(), scalars(0, 1)),
            "rpy": st.one_of(st.none(), arrays((3,))),
            "margin": st.one_of(st.none(), scalars(0, 0.1)),
        },
    ),
    # Features
    "Features": Target(
        lambda: None,
        lambda _, **kw: phri.Features(JACO2, scene=phri.Scene([TABLE, LAPTOP]), **kw).phi(
            np.tile(Q_MID, (5, 1))
        ),
        {
            "features": st.lists(
                st.one_of(
                    names(["efficiency", "table", "coffee", "origin", "laptop"]),
                    st.fixed_dictionaries(
                        {
                            "name": st.just("laptop"),
                            "keep_out": names(["laptop", "table"]),
                            "radius": scalars(0, 1),
                        },
                        optional={"offset": arrays((2,)), "samples": ints(1, 8)},
                    ),
                    st.fixed_dictionaries({"name": st.just("table"), "height": scalars(-1, 1)}),
                ),
                max_size=4,
            ),
            "frame": st.one_of(st.none(), names(FRAMES)),
            "ranges": st.one_of(st.none(), arrays((None,), 0.1, 10)),
        },
    ),
    "Features.evaluate": Target(
        _features,
        lambda f, *, method, **kw: getattr(f, method)(**kw),
        {"method": st.sampled_from(["phi", "phi_gradient", "per_segment"]), "xi": TRAJ},
    ),
    "Features.weighted_cost": Target(
        _features, lambda f, **kw: f.weighted_cost(**kw), {"xi": TRAJ, "weights": arrays((4,), -5, 5)}
    ),
    "Features.rescale_weights": Target(
        _features,
        lambda f, **kw: f.rescale_weights(**kw),
        {"weights": arrays((4,)), "from_waypoints": ints(2, 200), "to_waypoints": ints(2, 200)},
    ),
    # Learning pieces
    "WeightUpdate": Target(
        lambda: None,
        lambda _, **kw: (u := phri.WeightUpdate(**kw)).apply(np.ones(len(u)), np.ones(len(u))),
        {
            "step": arrays((3,), 0, 1),
            "lower": arrays((3,), -10, 0),
            "upper": arrays((3,), 0, 10),
            "learned": st.one_of(st.none(), st.lists(st.booleans(), min_size=2, max_size=4)),
            "ranges": st.one_of(st.none(), arrays((3,), 0, 5)),
            "rule": names(["all", "max", "confidence"]),
        },
    ),
    "WeightUpdate.apply": Target(
        lambda: phri.WeightUpdate([0.5, 0.5, 0.5], [-5.0] * 3, [5.0] * 3),
        lambda u, **kw: (u.apply(**kw), u.clip(kw["weights"])),
        {
            "weights": arrays((3,)),
            "delta_phi": arrays((3,)),
            "relevance": st.one_of(st.none(), arrays((3,), 0, 1)),
        },
    ),
    "relevance": Target(
        lambda: None,
        lambda _, **kw: phri.relevance(**kw),
        {"delta_phi": arrays((3,)), "sensitivity": arrays((3, N)), "u_h": VEC},
    ),
    "InteractionDetector": Target(
        lambda: None,
        lambda _, *, tau_measured, **kw: phri.InteractionDetector(**kw).detect(tau_measured),
        {
            "thresholds": st.one_of(st.none(), arrays((N,), 0, 10)),
            "bias": st.one_of(st.none(), arrays((N,))),
            "tau_measured": VEC,
        },
    ),
    "Deformation": Target(
        lambda: None,
        lambda _, *, trajectory, index, u_h, **kw: phri.Deformation(**kw).deform(trajectory, index, u_h),
        {
            "window": ints(1, 40),
            "mu": scalars(-1, 1),
            "norm": names(["acceleration", "jerk"]),
            "end_rule": names(["skip", "shrink"]),
            "trajectory": TRAJ,
            "index": ints(0, 40),
            "u_h": VEC,
        },
    ),
    "Deformation.window_at": Target(
        phri.Deformation,
        lambda d, **kw: d.window_at(**kw),
        {"index": ints(0, 50), "n_waypoints": ints(0, 50)},
    ),
    # Reference
    "TimedTrajectory": Target(
        lambda: None,
        lambda _, *, t, **kw: phri.TimedTrajectory(**kw).sample(t),
        {
            "waypoints": TRAJ,
            "duration": scalars(0, 30),
            "interpolation": names(["cubic", "linear"]),
            "t": scalars(-5, 40),
        },
    ),
    "TimedTrajectory.use": Target(  # a fresh trajectory per example: the same input, the same outcome
        lambda: None,
        lambda _, **kw: _use_trajectory(**kw),
        {
            "times": arrays((None,), -5, 40),
            "t": scalars(-5, 40),
            "waypoints": arrays((11, N)),
            "speed_limits": st.one_of(st.none(), arrays((N,), 0, 3)),
        },
    ),
    # Control
    "ImpedanceController": Target(
        lambda: None,
        lambda _, **kw: phri.ImpedanceController(JACO2, scene=phri.Scene([TABLE]), **kw).torque(
            Q_MID, np.zeros(N), Q_MID, np.zeros(N)
        ),
        {
            "stiffness": st.one_of(st.none(), arrays((N,), 0, 100), arrays((N, N), 0, 100)),
            "damping": st.one_of(st.none(), arrays((N,), 0, 20)),
            "inertia": st.one_of(st.none(), arrays((N,), 0, 5)),
            "wall_margin": scalars(0, 0.05),
            "wall_band": scalars(0, 0.05),
            "wall_stiffness": scalars(0, 1e4),
            "wall_damping": scalars(0, 500),
        },
    ),
    "ImpedanceController.torque": Target(
        lambda: phri.ImpedanceController(JACO2, scene=phri.Scene([TABLE])),
        lambda c, *, method, dt, **kw: (
            c.torque(**kw)
            if method == "torque"
            else c.torque_implicit(dt=dt, **kw)
            if method == "torque_implicit"
            else c.torque_full(qdd_ref=kw["qd_ref"], u_h=kw["qd"], **kw)
        ),  # fmt: skip
        {
            "method": st.sampled_from(["torque", "torque_implicit", "torque_full"]),
            "q": VEC,
            "qd": VEC,
            "q_ref": VEC,
            "qd_ref": VEC,
            "dt": scalars(0, 0.01),
        },
    ),
    # Planning
    "TrajectoryOptimizer": Target(
        _features,
        lambda f, **kw: phri.TrajectoryOptimizer(f, collisions=False, **kw).solve(
            [1, 1, 1, 1], Q_MID, Q_MID + 0.1
        )[1],
        {
            "waypoints": ints(3, 15),
            "duration": st.one_of(st.none(), scalars(0, 20)),
            "speed_fraction": scalars(0, 1),
            "max_iterations": ints(1, 10),
            "max_time": st.one_of(st.none(), scalars(0, 1)),
            "gradient_tolerance": scalars(0, 1),
            "smoothing": scalars(0, 0.1),
            "coarsening": ints(0, 5),
            "coarsest": ints(3, 10),
            "kinematic_curvature": names(["gauss-newton", "settled", "exact"]),
        },
        weight=0.5,
    ),
    "TrajectoryOptimizer.solve": Target(
        _optimizer,
        lambda o, **kw: o.solve(**kw),
        {
            "weights": arrays((4,), -2, 5),
            "start": VEC,
            "goal": VEC,
            "init": st.one_of(st.none(), arrays((11, N), -2, 2)),
        },
        weight=0.5,
    ),
    "TrajectoryOptimizer.objective": Target(
        _optimizer, lambda o, **kw: o.objective(**kw), {"xi": arrays((11, N)), "weights": arrays((4,), -5, 5)}
    ),
    "PlanLevels.level": Target(_levels, lambda ol, **kw: ol[1].level(**kw), {"k": ints(0, 3)}),
    # The learner
    "Learner": Target(
        _learner_parts,
        lambda parts, **kw: phri.Learner(**parts, **kw).reference(1.0),
        {
            "weights": arrays((2,), -2, 5),
            "start": VEC,
            "goal": VEC,
            "duration": scalars(0, 30),
            "sample_period": scalars(0, 1),
            "transition_speed": scalars(0, 2),
            "replan_iterations": ints(0, 20),
            "seeds": ints(0, 4),
            "replan_latency": st.one_of(st.none(), scalars(0, 0.5)),
        },
        weight=0.5,
    ),
    "Learner.observe": Target(  # a fresh learner per example
        lambda: None,
        lambda _, **kw: ((ln := _learner()).observe(**kw), ln.reference(kw["t"])),
        {"t": scalars(-1, 10), "tau_measured": VEC},
        weight=0.5,
    ),
    # Configuration
    "load_task": Target(
        lambda: None,
        lambda _, **kw: phri.load_task(**kw).duration,
        {"name_or_path": st.one_of(names(phri.task_names()), _path_variants())},
    ),
}


# The task parser (Python: phri.config) on task files near the shipped ones.
TASK_FILE = Path(tempfile.mkdtemp(prefix="phri-fuzz-task-")) / "task.toml"
TOML_VALUES = st.one_of(
    st.integers(-(2**70), 2**70).map(str),
    st.sampled_from(
        ["nan", "inf", "-inf", "1e308", "-1e308", "5e-324", "0", "-0.0", "true", '""', '"x"', "[]"]
    ),
    st.sampled_from(['"../x"', '"a\\u0000b"', '"' + "é" * 300 + '"', "[[[[1]]]]", "{a = 1}", "9" * 5000]),
    st.floats(allow_nan=False, allow_infinity=False).map(repr),
    st.lists(st.floats(-10, 10).map(repr), max_size=9).map(lambda v: "[" + ", ".join(v) + "]"),
)


@st.composite
def mutated_texts(draw: st.DrawFn, texts: list[str]) -> str:
    """One of `texts` (a shipped file) with a few of its values replaced, lines dropped or doubled,
    or text put in."""
    lines = draw(st.sampled_from(texts)).splitlines()
    for _ in range(draw(st.integers(1, 3))):
        i = draw(st.integers(0, len(lines) - 1))
        match draw(st.sampled_from(["value", "value", "drop", "double", "insert"])):
            case "value" if "=" in lines[i]:
                lines[i] = lines[i].split("=", 1)[0] + "= " + draw(TOML_VALUES)
            case "drop":
                del lines[i]
            case "double":
                lines.insert(i, lines[i])
            case "insert":
                lines.insert(i, draw(st.text(max_size=30)))
            case _:
                pass
        if not lines:
            break
    return "\n".join(lines) + "\n"


def task_texts() -> st.SearchStrategy[str]:
    return mutated_texts([(files("phri") / "tasks" / f"{n}.toml").read_text() for n in phri.task_names()])


def _load_task_text(_: Any, *, text: str) -> Any:
    TASK_FILE.write_text(text, encoding="utf-8", errors="surrogatepass")
    return phri.load_task(TASK_FILE).duration


TARGETS["load_task.file"] = Target(
    lambda: None, _load_task_text, {"text": task_texts()}, extra={"names": [str(TASK_FILE)]}
)

# The population parser (phri.sim.participant.population) on files near the shipped one, and a draw.
POPULATION_FILE = TASK_FILE.with_name("population.toml")


def _load_population_text(_: Any, *, text: str, study_seed: Any, participant: Any) -> Any:
    POPULATION_FILE.write_text(text, encoding="utf-8", errors="surrogatepass")
    return load_population(POPULATION_FILE).draw(study_seed, participant).as_dict()


TARGETS["load_population.file"] = Target(
    lambda: None,
    _load_population_text,
    {
        "text": mutated_texts([(files("phri") / "populations" / "default.toml").read_text()]),
        "study_seed": ints(0, 100),
        "participant": ints(0, 100),
    },
    extra={"names": [str(POPULATION_FILE)]},
)


# Robot descriptions (phri.robots) near the shipped ones (each beside a copy of its URDFs), read into
# the robot, its impedance law and the safety layer's limits for its table task.
ROBOT_TASKS = {"jaco2": "table", "fr3": "fr3_table"}
ROBOT_FOLDERS = {r: TASK_FILE.with_name(f"robot-{r}") for r in ROBOT_TASKS}
for _name, _folder in ROBOT_FOLDERS.items():
    shutil.copytree(Path(str(files("phri") / "robots" / _name)), _folder)


def _robot_description_text(_: Any, *, description: tuple[str, str]) -> Any:
    name, text = description
    path = ROBOT_FOLDERS[name] / "robot.toml"
    path.write_text(text, encoding="utf-8", errors="surrogatepass")
    robot = phri.Robot.from_description(path)
    loaded = load_description(path)
    q = (robot.lower_limits.clip(-3, 3) + robot.upper_limits.clip(-3, 3)) / 2
    torque = impedance_controller(robot, loaded).torque(q, np.zeros(robot.nq), q + 0.01, np.zeros(robot.nq))
    return safety_limits(robot, loaded, phri.load_task(ROBOT_TASKS[name])), torque


TARGETS["robot_description.file"] = Target(
    lambda: None,
    _robot_description_text,
    {
        "description": st.sampled_from(sorted(ROBOT_TASKS)).flatmap(
            lambda r: mutated_texts([(files("phri") / "robots" / r / "robot.toml").read_text()]).map(
                lambda text: (r, text)
            )
        )
    },
    extra={"names": [str(f / "robot.toml") for f in ROBOT_FOLDERS.values()]},
    weight=0.5,
)


# The control loop's safety layer and the loop itself (phri.control), on the JACO2's limits for the
# table task.
LIMITS = safety_limits(JACO2, "jaco2", phri.load_task("table"))
PERIOD = 1e-3


def _safety_layer(**kw: Any) -> SafetyLayer:
    return LIMITS.layer(JACO2, period=PERIOD, gravity_compensated=True, **kw)


def _safety_tick(layer: SafetyLayer, t: Any, q: Any, qd: Any, tau_ext: Any, tau: Any) -> Any:
    """One tick of the layer (fresh per example: it keeps the clock); what it commands must be
    finite whatever it was given."""
    layer.reset()
    command = np.zeros(N)
    return layer.check_state(t, q, qd, tau_ext), layer.limit_torque(q, tau, command), command


READING = st.lists(reals(-5.0, 5.0), min_size=N, max_size=N).map(np.array)


def _control_loop(*, fault: tuple[int, str, Any], q_start: Any, duration: Any, **kw: Any) -> Any:
    at, field, reading = fault
    # The reading (the robot's clock, q, qd or tau_ext) replaced from tick `at` on: a sensor fault,
    # a frozen clock.
    arm = FakeArm(
        JACO2, Q_MID, period=PERIOD, gravity_compensated=True,
        script=lambda k, state: setattr(state, field, reading) if k >= at else None,
    )  # fmt: skip
    loop = ControlLoop(
        arm, _learner(), phri.ImpedanceController(JACO2, gravity_compensation=True), LIMITS, **kw
    )
    result = loop.run(q_start, duration, check=False)
    return (result.stop.reason if result.stop else None), np.array(arm.commands)


TARGETS["SafetyLayer"] = Target(
    lambda: None,
    lambda _, **kw: _safety_tick(
        SafetyLayer(JACO2, **kw), 0.0, Q_MID, np.zeros(N), np.zeros(N), JACO2.gravity(Q_MID)
    ),
    {
        "tool": names([*FRAMES[-2:]]),
        "position_lower": arrays((N,), -7, 0),
        "position_upper": arrays((N,), 0, 7),
        "velocity": arrays((N,), 0, 2),
        "torque": arrays((N,), 0, 40),
        "torque_rate": arrays((N,), 0, 5000),
        "tool_box": st.one_of(st.none(), st.tuples(arrays((3,), -2, 0), arrays((3,), 0, 2))),
        "period": scalars(0, 0.01),
        "late_after": scalars(0, 5),
        "late_ticks": ints(1, 5),
        "gravity_compensated": st.booleans(),
    },
)
TARGETS["SafetyLayer.tick"] = Target(  # a fresh layer per example
    lambda: None,
    lambda _, **kw: _safety_tick(_safety_layer(), **kw),
    {
        "t": scalars(-1, 1),
        "q": st.one_of(VEC, READING),
        "qd": st.one_of(VEC, READING),
        "tau_ext": st.one_of(VEC, READING),
        "tau": st.one_of(arrays((N,), -50, 50), READING),
    },
)
TARGETS["ControlLoop"] = Target(  # a run of at most 50 ticks with a reading gone bad at some tick
    lambda: None,
    lambda _, **kw: _control_loop(**kw),
    {
        "fault": st.tuples(
            st.integers(0, 40),
            st.sampled_from(["t", "q", "qd", "tau_ext"]),
            st.one_of(READING, reals(-1, 1)),
        ).map(lambda f: f if (f[1] == "t") == isinstance(f[2], float) else (f[0], "t", 0.0)),
        # Mostly valid settings, so that most examples run ticks and meet the bad reading.
        "q_start": st.one_of(st.just(Q_MID), st.just(Q_MID), VEC),
        "duration": st.one_of(st.just(0.04), st.just(0.04), scalars(0, 0.05)),
        "hold_time": st.one_of(st.just(0.01), st.just(0.01), scalars(0, 0.02)),
        "late_ticks": st.one_of(st.just(3), st.just(3), ints(1, 5)),
        "late_after": st.one_of(st.just(1.5), st.just(1.5), scalars(0, 5)),
        "log_rate": st.one_of(st.just(100.0), st.just(100.0), scalars(0, 1000)),
        "implicit": st.booleans(),
    },
    weight=0.5,
)

# The simulated participant (phri.sim.participant): one person's parameters, and population files
# near the shipped one.
TABLE_TASK = phri.load_task("table")
TABLE_PLAN = np.array([TABLE_TASK.start, TABLE_TASK.goal])


def _person(params: ParticipantParams) -> Any:
    """The person with `params` watching the table task for a few of their looks."""
    person = Participant(params, TABLE_TASK, JACO2, TABLE_PLAN, np.random.default_rng(0))
    q = TABLE_TASK.start + 0.2
    return [person.wrench(0.05 * k, q) for k in range(8)]


TARGETS["ParticipantParams"] = Target(
    lambda: None,
    lambda _, *, attempt, **kw: _person(ParticipantParams(**kw).for_attempt(attempt)),
    {
        "tolerance": scalars(0, 0.1),
        "release": scalars(0, 1),
        "delay": scalars(0, 1),
        "max_force": scalars(0, 50),
        "bout": scalars(0, 5),
        "practice": scalars(0, 1),
        "rate": scalars(0, 20),
        "attempt": ints(1, 5),
    },
)


# -- checking a call ------------------------------------------------------------------------------


def finite(out: Any, depth: int = 0) -> bool:
    """Every float in `out` (arrays, tuples, lists, dicts, phri's result objects) is finite."""
    if depth > 4 or out is None or isinstance(out, bool | int | str | bytes):
        return True
    if isinstance(out, float):
        return math.isfinite(out)
    if isinstance(out, np.ndarray):
        return out.dtype.kind not in "fc" or bool(np.isfinite(out).all())
    if isinstance(out, list | tuple):
        return all(finite(o, depth + 1) for o in out)
    if isinstance(out, dict):
        return all(finite(o, depth + 1) for o in out.values())
    if type(out).__module__ == "phri._phri" and type(out).__name__ in ("TrajoptInfo", "UpdateInfo"):
        return all(finite(getattr(out, a), depth + 1) for a in dir(out) if not a.startswith("_"))
    return True


def _shown(v: Any) -> Any:
    """A short form of an argument for the log of calls."""
    if isinstance(v, np.ndarray):
        return f"<ndarray {v.dtype} {v.shape}>"
    if isinstance(v, list | str):
        return f"<{type(v).__name__} of {len(v)}>"
    return v


def check(name: str, obj: Any, target: Target, kwargs: dict[str, Any]) -> None:
    """Calls the target and checks its outcome (see the module docs)."""
    shown = {k: _shown(v) for k, v in kwargs.items()}
    print(f"CALL {name} {shown}", file=sys.stderr, flush=True)
    try:
        out = target.call(obj, **kwargs)
    except (PlanningError, NotConvergedError):
        return
    except PhriError as e:
        message = str(e)
        # An argument's name, or for a file or name the value given (ConfigError names the file).
        given = [str(v) for v in kwargs.values() if isinstance(v, str | os.PathLike) and str(v)]
        given += target.extra.get("names", [])
        assert any(k in message for k in [*kwargs, *given]) or "features[" in message, (
            f"{name}: {type(e).__name__} names none of the arguments {list(kwargs)}: {message}"
        )
        return
    except TypeError as e:
        message = str(e)
        assert any(k in message for k in kwargs) or "argument" in message, (
            f"{name}: TypeError names no argument: {message}"
        )
        return
    assert finite(out), f"{name}: a result that is not finite: {out!r}"


def run(name: str, examples: int) -> None:
    target = TARGETS[name]
    obj = target.setup()

    @settings(
        max_examples=max(1, int(examples * target.weight)),
        derandomize=True,
        database=None,
        deadline=None,
        suppress_health_check=list(HealthCheck),
        print_blob=False,
    )
    @given(st.fixed_dictionaries(target.args))
    def fuzz(kwargs: dict[str, Any]) -> None:
        check(name, obj, target, kwargs)

    fuzz()


if __name__ == "__main__":
    run(sys.argv[1], int(sys.argv[2]))
