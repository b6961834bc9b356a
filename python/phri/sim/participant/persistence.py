"""When the person pushes, pauses, re-tries and gives up.

A person does not hold on to a robot forever. Acting on what they see (with their visuomotor delay,
:mod:`phri.sim.participant.model`), they:

1. **grab** the arm as soon as an error they can fix is visible (beyond their tolerance);
2. **push** in bouts: once the error looks fixed (below ``release`` × their tolerance) they hold on
   for ``hold`` [s] to make sure it stays so, then let go; they also let go after ``bout`` [s] of
   pushing at once, to see what the robot does on its own;
3. **pause**: after letting go they watch for ``pause`` [s] before they may grab again; if the robot
   springs back (the error is visible again), they re-try;
4. **give up**: once they have pushed ``patience`` [s] in total in this attempt, they stop pushing
   for the rest of it. A robot that learns stays corrected after a bout or two, so patience rarely
   runs out; an impedance robot springs back every time, so it is what ends the interaction.
"""

from __future__ import annotations

from enum import Enum

from phri.sim.participant.params import ParticipantParams

__all__ = ["Persistence", "State"]

#: Slack on time comparisons [s] (the person's clock ticks in floating-point periods).
_SLACK = 1e-9


class State(Enum):
    """What the person is doing: watching for an error they can fix, pushing (a bout), pausing after
    letting go, or given up for the rest of the attempt (their ``patience`` [s] spent)."""

    WATCHING = "watching"
    PUSHING = "pushing"
    PAUSING = "pausing"
    GAVE_UP = "gave up"


class Persistence:
    """The person's decision to push, updated every `period` [s]."""

    def __init__(self, params: ParticipantParams, period: float) -> None:
        self.params, self.period = params, period
        self.state = State.WATCHING
        #: When the current state began [s], and since when the error has looked fixed (None: not).
        self.since = 0.0
        self.fixed_since: float | None = None
        #: Time pushed in this attempt so far [s], and bouts begun.
        self.pushed = 0.0
        self.bouts = 0

    def _enter(self, state: State, t: float) -> None:
        self.state, self.since, self.fixed_since = state, t, None

    def update(self, t: float, visible: bool, fixed: bool) -> bool:
        """Whether the person pushes at time `t` [s], given whether a fixable error is visible (beyond
        their tolerance) and whether every error looks fixed (below their release threshold)."""
        p = self.params
        if self.state is State.PUSHING:
            self.pushed += self.period
            if not fixed:
                self.fixed_since = None
            elif self.fixed_since is None:
                self.fixed_since = t
            held = self.fixed_since is not None and t - self.fixed_since >= p.hold - _SLACK
            if held or t - self.since >= p.bout - _SLACK or self.pushed >= p.patience - _SLACK:
                self._enter(State.PAUSING, t)
        elif self.state is State.PAUSING and t - self.since >= p.pause - _SLACK:
            self._enter(State.WATCHING, t)
        if self.state is State.WATCHING and visible:
            if self.pushed >= p.patience - _SLACK:
                self._enter(State.GAVE_UP, t)
            else:
                self._enter(State.PUSHING, t)
                self.bouts += 1
        return self.state is State.PUSHING
