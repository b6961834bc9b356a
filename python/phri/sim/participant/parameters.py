"""The participant model's parameters: name, SI unit, meaning and allowed range, in one place (read
by :class:`~phri.sim.participant.params.ParticipantParams`, the population files and the docs)."""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["PARAMETERS", "Parameter"]


@dataclass(frozen=True)
class Parameter:
    """What a participant parameter means and which values it may take."""

    unit: str
    meaning: str
    #: Smallest allowed value, and whether the value must be strictly above it.
    low: float = 0.0
    above: bool = False
    #: Largest allowed value (inclusive unless `below`).
    high: float = math.inf
    below: bool = False

    def allows(self, v: float) -> bool:
        """Whether `v` (in the parameter's `unit`) is an allowed value: finite and within `low` and
        `high` (strictly where `above` or `below` say so)."""
        if not math.isfinite(v):
            return False
        low_ok = v > self.low if self.above else v >= self.low
        high_ok = v < self.high if self.below else v <= self.high
        return low_ok and high_ok

    @property
    def expected(self) -> str:
        """The allowed range in words, for error messages: e.g. ``"a finite number > 0"`` or
        ``"a number >= 0 and <= 1"``."""
        lo = f"> {self.low:g}" if self.above else f">= {self.low:g}"
        if math.isinf(self.high):
            return f"a finite number {lo}"
        hi = f"< {self.high:g}" if self.below else f"<= {self.high:g}"
        return f"a number {lo} and {hi}"


#: Every parameter of the model, in the order ParticipantParams lists them.
PARAMETERS: dict[str, Parameter] = {
    # Perception (phri.sim.participant.perception): when a task feature is visibly wrong.
    "tolerance": Parameter(
        "m", "how far the cup may be from where the task wants it before they see it", above=True
    ),
    "tilt_tolerance": Parameter(
        "rad", "how far the cup may tilt beyond the task's wish before they see it", above=True
    ),
    "release": Parameter("-", "they let go once the error is below this fraction of the tolerance", high=1.0),
    "delay": Parameter("s", "visuomotor delay: they grab, let go and aim by what they saw this long ago"),
    # The arm (phri.sim.participant.arm): how hard they push.
    "stiffness": Parameter("N/m", "their arm's stiffness towards where the cup should be"),
    "rotational_stiffness": Parameter("N·m/rad", "their wrist's stiffness towards the upright cup"),
    "max_force": Parameter("N", "the most force they push the hand with"),
    "max_torque": Parameter("N·m", "the most torque they twist the hand with"),
    "rise_time": Parameter("s", "time constant of their push building up (muscle activation)"),
    "off_axis": Parameter("-", "size of a push's part across the direction that fixes the error, per push"),
    "noise": Parameter("N", "tremor: Gaussian SD per axis of the force (of the torque: × 0.1 m, in N·m)"),
    # Persistence (phri.sim.participant.persistence): pauses, retries, giving up.
    "bout": Parameter(
        "s", "the longest they push at once before letting go to see what the robot does", above=True
    ),
    "hold": Parameter("s", "how long they keep holding once the error looks fixed, to see it stays so"),
    "pause": Parameter("s", "how long they watch after letting go before they may push again"),
    "patience": Parameter("s", "total pushing per attempt they spend on a robot that keeps springing back"),
    # Practice (phri.sim.participant.params.ParticipantParams.for_attempt).
    "practice": Parameter(
        "-",
        "per earlier attempt, the fraction by which delay, hold, bout and patience shrink",
        high=1.0,
        below=True,
    ),
    "rate": Parameter("Hz", "how often they re-judge what they see and update their push", above=True),
}
