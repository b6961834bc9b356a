# Type stubs of the native module (checked against it by `make lint`: mypy.stubtest).
from collections.abc import Sequence
from os import PathLike
from typing import Any, ClassVar, Literal, final

import numpy as np
import numpy.typing as npt

__all__ = [
    "Deformation",
    "Features",
    "ImpedanceController",
    "InteractionDetector",
    "Learner",
    "Robot",
    "TimedTrajectory",
    "TrajectoryOptimizer",
    "TrajoptInfo",
    "UpdateInfo",
    "WeightUpdate",
    "__version__",
    "relevance",
]

__version__: str

_Array = npt.ArrayLike
_F64 = npt.NDArray[np.float64]

@final
class Robot:
    """A serial-chain robot (kinematics and rigid-body dynamics), read from a URDF."""

    @staticmethod
    def from_urdf(path: str | PathLike[str], base: str | None = None, tip: str | None = None) -> Robot: ...
    @staticmethod
    def from_urdf_string(urdf: str, base: str | None = None, tip: str | None = None) -> Robot: ...
    @staticmethod
    def jaco2() -> Robot: ...
    def with_payload(
        self, frame: str, mass: float, com: _Array | None = None, inertia: _Array | None = None
    ) -> Robot: ...
    @property
    def name(self) -> str: ...
    @property
    def nq(self) -> int: ...
    @property
    def joint_names(self) -> list[str]: ...
    @property
    def frame_names(self) -> list[str]: ...
    @property
    def lower_limits(self) -> _F64: ...
    @property
    def upper_limits(self) -> _F64: ...
    @property
    def velocity_limits(self) -> _F64: ...
    @property
    def effort_limits(self) -> _F64: ...
    def check_limits(self, q: _Array) -> None: ...
    def frame_pose(self, frame: str, q: _Array) -> _F64: ...
    def jacobian(self, frame: str, q: _Array) -> _F64: ...
    def gravity(self, q: _Array) -> _F64: ...
    def inverse_dynamics(self, q: _Array, qd: _Array, qdd: _Array) -> _F64: ...
    def nonlinear_effects(self, q: _Array, qd: _Array) -> _F64: ...
    def mass_matrix(self, q: _Array) -> _F64: ...

@final
class Features:
    """Task features Φ(ξ) of an (N, n) trajectory, summed over segments (q_{i-1}, q_i], i = 1..N-1."""

    def __new__(
        cls,
        robot: Robot,
        names: Sequence[str],
        frame: str = "j2s7s300_link_7",
        *,
        table_height: float = 0.0,
        laptop_center: tuple[float, float] = (-0.7929, -0.1),
        human_center: tuple[float, float] = (0.0, 0.2),
        radius: float = 0.4,
        samples: int = 4,
        ranges: _Array | None = None,
    ) -> Features: ...
    @property
    def names(self) -> list[str]: ...
    @property
    def ranges(self) -> _F64: ...
    def index(self, name: str) -> int: ...
    def phi(self, xi: _Array) -> _F64: ...
    def phi_gradient(self, xi: _Array) -> tuple[_F64, _F64]: ...
    def per_segment(self, xi: _Array) -> _F64: ...
    def weighted_cost(self, xi: _Array, weights: _Array) -> tuple[float, _F64]: ...
    def __len__(self) -> int: ...

@final
class UpdateInfo:
    """What one weight update did."""

    @property
    def chosen(self) -> int | None: ...
    @property
    def clipped(self) -> bool: ...
    @property
    def max_change(self) -> float: ...
    def __eq__(self, value: object, /) -> bool: ...
    __hash__: ClassVar[None]  # type: ignore[assignment]

@final
class WeightUpdate:
    """w ← clip(w − α ⊙ ΔΦ, lower, upper) by rule "all", "max" or "confidence"."""

    def __new__(
        cls,
        step: _Array,
        lower: _Array,
        upper: _Array,
        *,
        learned: Sequence[bool] | None = None,
        ranges: _Array | None = None,
        rule: Literal["all", "max", "confidence"] = "all",
    ) -> WeightUpdate: ...
    @property
    def step(self) -> _F64: ...
    @property
    def lower(self) -> _F64: ...
    @property
    def upper(self) -> _F64: ...
    @property
    def learned(self) -> npt.NDArray[np.bool_]: ...
    @property
    def ranges(self) -> _F64: ...
    @property
    def rule(self) -> str: ...
    def apply(
        self, weights: _Array, delta_phi: _Array, relevance: _Array | None = None
    ) -> tuple[_F64, UpdateInfo]: ...
    def clip(self, weights: _Array) -> _F64: ...
    def __len__(self) -> int: ...

def relevance(delta_phi: _Array, sensitivity: _Array, u_h: _Array) -> _F64: ...

@final
class InteractionDetector:
    """Per-joint torque thresholds [N·m] (default the JACO2's 8, 8, 8, 2, 1, 1, 1) and bias."""

    def __new__(cls, thresholds: _Array | None = None, bias: _Array | None = None) -> InteractionDetector: ...
    @property
    def thresholds(self) -> _F64: ...
    @property
    def bias(self) -> _F64: ...
    def detect(self, tau_measured: _Array) -> tuple[bool, _F64]: ...

@final
class TimedTrajectory:
    """(N, n) waypoints evenly spaced over [0, duration] s, interpolated "cubic" or "linear"."""

    def __new__(
        cls, waypoints: _Array, duration: float, interpolation: Literal["cubic", "linear"] = "cubic"
    ) -> TimedTrajectory: ...
    def sample(self, t: float) -> tuple[_F64, _F64, _F64]: ...
    def sample_many(self, times: _Array) -> tuple[_F64, _F64, _F64]: ...
    def index_at(self, t: float) -> int: ...
    def set_waypoints(self, waypoints: _Array) -> None: ...
    @property
    def waypoints(self) -> _F64: ...
    @property
    def duration(self) -> float: ...
    @property
    def dt(self) -> float: ...
    @property
    def dof(self) -> int: ...
    @property
    def interpolation(self) -> str: ...
    def __len__(self) -> int: ...

@final
class ImpedanceController:
    """Impedance law: eq. 6 (`torque`) or, with a desired inertia, eq. 5 (`torque_full`) [N·m]."""

    def __new__(
        cls,
        robot: Robot,
        *,
        stiffness: _Array | None = None,
        damping: _Array | None = None,
        inertia: _Array | None = None,
        gravity_compensation: bool = True,
    ) -> ImpedanceController: ...
    def torque(
        self, q: _Array, qd: _Array, q_ref: _Array, qd_ref: _Array, out: _F64 | None = None
    ) -> _F64: ...
    def torque_implicit(
        self, q: _Array, qd: _Array, q_ref: _Array, qd_ref: _Array, dt: float, out: _F64 | None = None
    ) -> _F64: ...
    def torque_full(
        self,
        q: _Array,
        qd: _Array,
        q_ref: _Array,
        qd_ref: _Array,
        qdd_ref: _Array,
        u_h: _Array,
        out: _F64 | None = None,
    ) -> _F64: ...
    @property
    def saturated(self) -> int: ...
    @property
    def effort_limits(self) -> _F64: ...
    @property
    def stiffness(self) -> _F64: ...
    @property
    def damping(self) -> _F64: ...
    @property
    def inertia(self) -> _F64 | None: ...
    @property
    def gravity_compensation(self) -> bool: ...

@final
class Deformation:
    """ξ_H = ξ_R + μ·A⁻¹·U_H (eq. 7): a push at `index` moves the next `window` waypoints by μ·H·u_H."""

    def __new__(
        cls,
        *,
        window: int = 5,
        mu: float = 0.01,
        norm: Literal["acceleration", "jerk"] = "acceleration",
        end_rule: Literal["skip", "shrink"] = "skip",
    ) -> Deformation: ...
    def deform(self, trajectory: _Array, index: int, u_h: _Array) -> _F64: ...
    def window_at(self, index: int, n_waypoints: int) -> int: ...
    @property
    def window(self) -> int: ...
    @property
    def mu(self) -> float: ...
    @property
    def norm(self) -> str: ...
    @property
    def end_rule(self) -> str: ...
    @property
    def shape(self) -> _F64: ...

@final
class TrajoptInfo:
    """What a trajectory optimisation did."""

    @property
    def iterations(self) -> int: ...
    @property
    def evaluations(self) -> int: ...
    @property
    def cost(self) -> float: ...
    @property
    def penalty(self) -> float: ...
    @property
    def max_violation(self) -> float: ...
    @property
    def converged(self) -> bool: ...
    @property
    def seconds(self) -> float: ...

@final
class TrajectoryOptimizer:
    """ξ_R = argmin w·Φ(ξ) (eq. 4) over N waypoints, start and goal fixed, joint limits as bounds."""

    def __new__(
        cls,
        features: Features,
        waypoints: int = 31,
        *,
        clearance: Sequence[tuple[str, float]] | None = None,
        clearance_weight: float = 1e3,
        max_iterations: int = 500,
        max_time: float | None = None,
        gradient_tolerance: float = 1e-6,
        relative_tolerance: float = 1e-10,
        memory: int = 20,
        smoothing: float = 0.05,
        max_step: _Array | None = None,
        step_weight: float = 1e3,
        method: Literal["newton", "lbfgs"] = "newton",
    ) -> TrajectoryOptimizer: ...
    @property
    def waypoints(self) -> int: ...
    @property
    def method(self) -> Literal["newton", "lbfgs"]: ...
    def objective(self, xi: _Array, weights: _Array) -> tuple[float, float, _F64]: ...
    def solve(
        self, weights: _Array, start: _Array, goal: _Array, init: _Array | None = None
    ) -> tuple[_F64, TrajoptInfo]: ...

@final
class Learner:
    """Algorithm 1: deform, update and replan at every sampled interaction."""

    def __new__(
        cls,
        features: Features,
        deformation: Deformation,
        update: WeightUpdate,
        detector: InteractionDetector,
        optimizer: TrajectoryOptimizer,
        weights: _Array,
        start: _Array,
        goal: _Array,
        *,
        duration: float = 15.0,
        sample_period: float = 0.1,
        interpolation: Literal["cubic", "linear"] = "cubic",
        learning: bool = True,
    ) -> Learner: ...
    def observe(self, t: float, tau_measured: _Array) -> tuple[bool, bool, bool]: ...
    def reference(self, t: float) -> tuple[_F64, _F64, _F64]: ...
    @property
    def weights(self) -> _F64: ...
    @property
    def plan(self) -> _F64: ...
    @property
    def learning(self) -> bool: ...
    def interactions(self) -> list[dict[str, Any]]: ...
    def plans(self) -> list[tuple[float, _F64]]: ...
