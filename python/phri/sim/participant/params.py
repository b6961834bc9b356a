"""One simulated person's parameters: what they tolerate, how hard and how long they push, and how
they learn between attempts (each in SI units; :data:`~phri.sim.participant.parameters.PARAMETERS`
says what each means and which values it may take).

A :class:`ParticipantParams` made without arguments is the default population's typical person:
every parameter at its distribution's median (:func:`phri.sim.participant.population.default_population`).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields, replace
from typing import TYPE_CHECKING

from phri.exceptions import InvalidParameterError
from phri.sim.participant.parameters import PARAMETERS

if TYPE_CHECKING:
    import numpy as np

__all__ = ["ParticipantParams"]


def _typical() -> dict[str, float]:
    from phri.sim.participant.population import default_population

    return default_population().typical()


_T = _typical()


@dataclass(frozen=True)
class ParticipantParams:
    """How one simulated person corrects the robot (see :data:`PARAMETERS` for each one's meaning).

    The defaults are the default population's medians."""

    tolerance: float = _T["tolerance"]  # m
    tilt_tolerance: float = _T["tilt_tolerance"]  # rad
    release: float = _T["release"]  # -
    delay: float = _T["delay"]  # s
    stiffness: float = _T["stiffness"]  # N/m
    rotational_stiffness: float = _T["rotational_stiffness"]  # N·m/rad
    max_force: float = _T["max_force"]  # N
    max_torque: float = _T["max_torque"]  # N·m
    rise_time: float = _T["rise_time"]  # s
    off_axis: float = _T["off_axis"]  # -
    noise: float = _T["noise"]  # N
    bout: float = _T["bout"]  # s
    hold: float = _T["hold"]  # s
    pause: float = _T["pause"]  # s
    patience: float = _T["patience"]  # s
    practice: float = _T["practice"]  # -
    rate: float = _T["rate"]  # Hz

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            spec = PARAMETERS[f.name]
            ok = isinstance(value, int | float) and not isinstance(value, bool) and spec.allows(float(value))
            if not ok:
                raise InvalidParameterError(f"{f.name} must be {spec.expected} [{spec.unit}], got {value!r}")
            object.__setattr__(self, f.name, float(value))

    @classmethod
    def draw(cls, rng: np.random.Generator) -> ParticipantParams:
        """One person from the default population, drawn from `rng` (see
        :meth:`phri.sim.participant.population.Population.draw_from`)."""
        from phri.sim.participant.population import default_population

        return default_population().draw_from(rng)

    def for_attempt(self, attempt: int) -> ParticipantParams:
        """This person on their `attempt`-th (1-based) try at a task: having seen the robot before,
        they react, let go and give up sooner, each by the fraction ``practice`` per earlier attempt (the
        paper saw a marginal improvement under impedance, none under learning: a robot that learns
        rarely exhausts anyone's patience, so only the impedance robot feels the difference)."""
        if isinstance(attempt, bool) or not isinstance(attempt, int) or attempt < 1:
            raise InvalidParameterError(f"attempt must be an integer >= 1, got {attempt!r}")
        keep = (1.0 - self.practice) ** (attempt - 1)
        return replace(
            self, delay=self.delay * keep, hold=self.hold * keep, bout=self.bout * keep,
            patience=self.patience * keep,
        )  # fmt: skip

    def as_dict(self) -> dict[str, float]:
        """Every parameter by name, in SI units, in :data:`PARAMETERS` order (a study's
        ``participants.csv`` lists each person this way)."""
        return asdict(self)
