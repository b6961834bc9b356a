"""Robot descriptions: per robot a URDF and, beside it, a ``robot.toml`` naming the modelled chain
(base and tip links), the frames phri uses (the features' point, the hand, the cup), what the
robot carries (one ``[carried.<name>]`` table per object: its URDF and the frame it is held at) and
the limits of the control loop's safety layer (``[safety]``, see :class:`SafetySpec`) and, for a
robot whose impedance gains are not the core's default (the JACO2's), its joint stiffness and
damping (``[impedance]``, read by :func:`impedance_controller`).

``Robot.jaco2()`` and ``Robot.from_description(path)`` read them through :func:`load`; the
simulation takes its frame names from the same description, so each lives in one file.
"""

from __future__ import annotations

from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING

from phri._validate import Reader, finite, parse_toml
from phri.exceptions import ConfigError

if TYPE_CHECKING:
    from phri._phri import ImpedanceController, Robot, Scene

__all__ = ["CarriedObject", "RobotDescription", "SafetySpec", "impedance_controller", "load", "read_safety"]

DESCRIPTION_KEYS = (
    "urdf", "base", "tip", "feature_frame", "hand_frame", "cup_frame", "carried", "interaction", "safety",
    "impedance",
)  # fmt: skip
#: The keys of a [safety] table's joint limits (a robot description's, or a task's overrides).
SAFETY_KEYS = ("position_margin", "velocity_limits", "torque_limits", "torque_rate_limit")
INTERACTION_KEYS = ("thresholds", "transition_speed")
IMPEDANCE_KEYS = ("stiffness", "damping")
CARRIED_KEYS = ("urdf", "frame")
#: The carried object whose frame is the description's `cup_frame`.
CUP = "cup"


@dataclass(frozen=True)
class CarriedObject:
    """An object the robot holds rigidly (the JACO2's cup): its URDF (whose collision geometry
    joins the robot's collision model, ``Robot.with_attached_urdf``) and the frame its root is
    held at."""

    source: str
    name: str
    urdf: Path
    frame: str

    def urdf_text(self) -> str:
        """The URDF's text; a missing or unreadable file is a ConfigError naming the description."""
        return _read(self.source, f"carried.{self.name}.urdf", self.urdf)


#: A per-joint limit as a [safety] table gives it: one number for every joint, or one per joint.
PerJoint = float | tuple[float, ...]


@dataclass(frozen=True)
class SafetySpec:
    """The joint limits of a ``[safety]`` table (the robot description's, or a task's overrides of
    them); None where the table says nothing. A value is one number for every joint or a list with
    one per joint (checked against the robot's joint count when the loop's limits are made,
    :func:`phri.control.safety_limits`).

    The loop stops the arm when a joint comes within `position_margin` [rad] of its URDF limit or
    moves faster than `velocity_limits` [rad/s] (default: the URDF's), and clips the torque to
    `torque_limits` [N·m] (default: the URDF's efforts) and the command's rate of change to
    `torque_rate_limit` [N·m/s] (the URDF has none: a description must give it to run the loop)."""

    source: str = "<memory>"
    position_margin: PerJoint | None = None
    velocity_limits: PerJoint | None = None
    torque_limits: PerJoint | None = None
    torque_rate_limit: PerJoint | None = None


def read_safety(r: Reader) -> SafetySpec:
    """The joint limits (SAFETY_KEYS) of the [safety] table `r` reads, whose keys its maker
    checked: each a finite number, or a list of them, > 0 (the margin >= 0); errors name the file
    and key."""
    values: dict[str, PerJoint] = {}
    for key in SAFETY_KEYS:
        if key not in r.table:
            continue
        raw = r.get(key)
        margin = key == "position_margin"
        expected = f"a number {'>= 0' if margin else '> 0'} or a list of them, one per joint"
        items = raw if isinstance(raw, list) else [raw]
        if not items or not all(finite(x) and (x >= 0 if margin else x > 0) for x in items):
            raise r.fail(key, expected, raw)
        values[key] = tuple(float(x) for x in items) if isinstance(raw, list) else float(raw)
    return SafetySpec(r.source, **values)


def _read(source: str, key: str, path: Path) -> str:
    try:
        return path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError, ValueError) as e:  # ValueError: a NUL in the path
        raise ConfigError(f"{source}: key '{key}': cannot read {path} ({e})") from None


@dataclass(frozen=True)
class RobotDescription:
    """What ``robot.toml`` says: the URDF file (relative to the description), the chain's base and
    tip links, and the frames phri uses (None where the description names none)."""

    source: str
    urdf: Path
    base: str
    tip: str
    feature_frame: str | None = None
    hand_frame: str | None = None
    #: Where the robot holds the cup: the key `cup_frame`, or the frame of [carried.cup].
    cup_frame: str | None = None
    #: What the robot carries, in the order of the file's tables.
    carried: tuple[CarriedObject, ...] = ()
    #: The interaction detector's per-joint thresholds [N·m] ([interaction] thresholds; None if
    #: the description gives none).
    thresholds: tuple[float, ...] | None = None
    #: The fastest blend into a new plan this robot allows, as a fraction of its rated joint
    #: velocities ([interaction] transition_speed; None: the episode's setting stands).
    transition_speed: float | None = None
    #: The safety layer's joint limits ([safety]; empty if the description has no such table).
    safety: SafetySpec = SafetySpec()
    #: The impedance law's joint stiffness [N·m/rad] and damping [N·m·s/rad] ([impedance]; None:
    #: the core's defaults, ``ImpedanceParams::jaco2_default``).
    stiffness: tuple[float, ...] | None = None
    damping: tuple[float, ...] | None = None

    def urdf_text(self) -> str:
        """The URDF's text; a missing or unreadable file is a ConfigError naming the description."""
        return _read(self.source, "urdf", self.urdf)


def load(name_or_path: str | Path) -> RobotDescription:
    """A shipped robot's description by name (``"jaco2"``) or a ``robot.toml`` by path."""
    path = Path(name_or_path)
    if path.is_dir():
        path = path / "robot.toml"
    elif path.suffix != ".toml":
        path = Path(str(resources.files("phri").joinpath("robots", str(name_or_path), "robot.toml")))
    if not path.is_file():
        raise ConfigError(f"{path}: robot description not found")
    source = str(path)
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as e:
        raise ConfigError(f"{source}: not valid TOML ({e})") from None
    data = parse_toml(text, source, "a robot description")
    r = Reader(source, data, allowed=DESCRIPTION_KEYS)
    frames = {key: r.optional_string(key) for key in ("feature_frame", "hand_frame", "cup_frame")}
    carried = _carried(r, path.parent)
    cup = next((c for c in carried if c.name == CUP), None)
    if cup is not None:  # the cup's frame has one home: its [carried.cup] table
        if frames["cup_frame"] not in (None, cup.frame):
            raise r.fail(
                "cup_frame", f"left out or the frame of [carried.{CUP}] ({cup.frame!r})", frames["cup_frame"]
            )
        frames["cup_frame"] = cup.frame
    interaction = r.table_of("interaction", INTERACTION_KEYS)
    thresholds = None
    if "thresholds" in interaction.table:
        raw = interaction.get("thresholds")
        count = len(raw) if isinstance(raw, list) else 0
        v = interaction.vector("thresholds", max(count, 1))
        if not (v > 0).all():
            raise interaction.fail("thresholds", "a list of positive numbers [N·m], one per joint", raw)
        thresholds = tuple(float(x) for x in v)
    transition_speed = None
    if "transition_speed" in interaction.table:
        transition_speed = interaction.number("transition_speed", expected="a fraction in (0, 1]")
        if not 0 < transition_speed <= 1:
            raise interaction.fail("transition_speed", "a fraction in (0, 1]", transition_speed)
    safety = read_safety(r.table_of("safety", SAFETY_KEYS))
    stiffness, damping = _gains(r.table_of("impedance", IMPEDANCE_KEYS))
    return RobotDescription(
        source, path.parent / r.string("urdf"), r.string("base"), r.string("tip"), **frames,
        carried=carried, thresholds=thresholds, transition_speed=transition_speed, safety=safety,
        stiffness=stiffness, damping=damping,
    )  # fmt: skip


def _gains(r: Reader) -> tuple[tuple[float, ...] | None, tuple[float, ...] | None]:
    """The [impedance] table's stiffness and damping (both or neither): lists of finite numbers > 0,
    one per joint (their count is checked against the robot when the controller is made)."""
    given = [key for key in IMPEDANCE_KEYS if key in r.table]
    if len(given) == 1:
        missing = next(key for key in IMPEDANCE_KEYS if key not in given)
        raise r.fail(missing, f"given with '{r.prefix}{given[0]}' (the two gains go together)")
    gains: dict[str, tuple[float, ...] | None] = {key: None for key in IMPEDANCE_KEYS}
    for key in given:
        raw = r.get(key)
        if not (isinstance(raw, list) and raw and all(finite(x) and x > 0 for x in raw)):
            raise r.fail(key, "a list of finite numbers > 0, one per joint", raw)
        gains[key] = tuple(float(x) for x in raw)
    return gains["stiffness"], gains["damping"]


def impedance_controller(
    robot: Robot, description: str | Path | RobotDescription, scene: Scene | None = None
) -> ImpedanceController:
    """The impedance law for `robot` with its description's gains (``[impedance]``; the core's
    defaults, the JACO2's, where it gives none), with g(q) (the control loop removes it for an arm
    that compensates gravity itself) and, with `scene`, the run-time clearance wall. The one place
    a robot's controller is made; a gain count that is not the robot's joint count is a ConfigError
    naming the file."""
    from phri._phri import ImpedanceController

    d = description if isinstance(description, RobotDescription) else load(description)
    for key in IMPEDANCE_KEYS:
        value = getattr(d, key)
        if value is not None and len(value) != robot.nq:
            raise ConfigError(
                f"{d.source}: key 'impedance.{key}' must have one value per joint ({robot.nq}), "
                f"got {len(value)}"
            )
    if d.stiffness is None:
        return ImpedanceController(robot, scene=scene)
    return ImpedanceController(robot, stiffness=list(d.stiffness), damping=list(d.damping or ()), scene=scene)


def _carried(r: Reader, folder: Path) -> tuple[CarriedObject, ...]:
    """The [carried.<name>] tables; each URDF path is relative to the description."""
    tables = r.named_tables("carried", "cup", "a table with urdf and frame", CARRIED_KEYS)
    return tuple(
        CarriedObject(r.source, name, folder / c.string("urdf"), c.string("frame")) for name, c in tables
    )
