"""Robot descriptions: per robot a URDF and, beside it, a ``robot.toml`` naming the modelled chain
(base and tip links) and the frames phri uses (the features' point, the hand, the cup).

``Robot.jaco2()`` and ``Robot.from_description(path)`` read them through :func:`load`; the
simulation takes its frame names from the same description, so each lives in one file.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

from phri._validate import Reader
from phri.exceptions import ConfigError

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

__all__ = ["RobotDescription", "load"]

DESCRIPTION_KEYS = ("urdf", "base", "tip", "feature_frame", "hand_frame", "cup_frame")


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
    cup_frame: str | None = None

    def urdf_text(self) -> str:
        """The URDF's text; a missing or unreadable file is a ConfigError naming the description."""
        try:
            return self.urdf.read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as e:
            raise ConfigError(f"{self.source}: key 'urdf': cannot read {self.urdf} ({e})") from None


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
        data: dict[str, Any] = tomllib.loads(path.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
        raise ConfigError(f"{source}: not valid TOML ({e})") from None
    r = Reader(source, data, allowed=DESCRIPTION_KEYS)
    frames = {key: r.optional_string(key) for key in ("feature_frame", "hand_frame", "cup_frame")}
    return RobotDescription(
        source, path.parent / r.string("urdf"), r.string("base"), r.string("tip"), **frames
    )
