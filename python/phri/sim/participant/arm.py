"""How hard the person pushes: a compliant human arm.

A person guiding a cup holds it with an arm that is itself a spring: they pull it towards where it
should be with a force that grows with the distance (their arm's stiffness, N/m, and their wrist's,
N·m/rad), never beyond what they are willing to apply (``max_force``, ``max_torque``), and their push
builds up and settles with the time constant of muscle activation (``rise_time``): a person does not
apply a step of force. As the robot yields, the distance and so the push shrink.

People push imprecisely: a push has a component across the direction that would fix the error, of
``off_axis`` times its size (the tangent of the push's direction error; the size of the push they are
willing to apply, force and twist capped at ``max_force`` and ``max_torque``), in a direction drawn anew for
each bout, and a twist of the cup comes with a force on the hand that grips it (and a force with a
twist) by the same rule, force and torque related by the lever ℓ = 0.1 m. This part changes nothing
the person cares about, so it teaches the robot nothing, but the robot's sensors feel it. On top rides
tremor, Gaussian noise of SD ``noise`` per axis (N; on a torque, the same noise at the lever ℓ, N·m),
and the push, all of it included, is what saturates.

Human pushes in pHRI are a few to a few tens of newtons; the default population's levels are fitted
to the study's measured effort per interaction sample (see docs/participant.md).
"""

from __future__ import annotations

import math

import numpy as np

from phri.sim.participant.params import ParticipantParams

__all__ = ["LEVER", "HumanArm"]

#: Lever relating a hand's force and torque (tremor, off-axis pushes) [m].
LEVER = 0.1
#: A relaxing push below this force [N] (and this × LEVER of torque [N·m]) has let go: hands off.
RELEASED = 0.1


def _saturate(v: np.ndarray, limit: float) -> np.ndarray:
    """`v` scaled down, keeping its direction, to a norm of at most `limit`."""
    norm = math.sqrt(float(v @ v))
    return v * (limit / norm) if norm > limit else v


#: A part of a push smaller than this fraction of the whole is rounding, without a direction [-].
NEGLIGIBLE = 1e-9


def _across(direction: np.ndarray, push: np.ndarray) -> np.ndarray:
    """The unit vector along `direction`'s part perpendicular to `push` (any direction if `push` is 0)."""
    norm2 = float(push @ push)
    d = direction - (float(direction @ push) / norm2) * push if norm2 > 0 else direction
    n = math.sqrt(float(d @ d))
    return d / n if n > 0 else d


class HumanArm:
    """The person's push for a wished move of the cup, updated every `period` [s]."""

    def __init__(self, params: ParticipantParams, rng: np.random.Generator, period: float) -> None:
        self.params = params
        # Own streams for tremor (drawn every update) and each bout's off-axis direction, so the
        # person's random numbers do not depend on when they push.
        self.tremor_rng, self.aim_rng = rng.spawn(2)
        #: This bout's off-axis directions (unit force and torque directions), None between bouts.
        self.across: np.ndarray | None = None
        #: Fraction of the way to the wished push covered per update (first-order activation).
        self.follow = 1.0 - math.exp(-period / params.rise_time) if params.rise_time > 0 else 1.0
        #: The push the muscles currently produce: force [N] and torque [N·m] (world frame).
        self.force = np.zeros(3)
        self.torque = np.zeros(3)

    def push(
        self, move: np.ndarray | None, lag: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray] | None:
        """The push for the wished `move` of the cup (translation [m], rotation [rad]; None: hands
        off). `lag` is how far the cup is from where the person expects it (the hand follows what
        the eyes saw, carried on: phri.sim.participant.model), a pull their arm's spring adds.

        Tremor is drawn at every update, pushing or not, so the person's random stream does not
        depend on when they push."""
        p = self.params
        tremor = self.tremor_rng.normal(0.0, 1.0, 6) * p.noise
        if move is None:
            # Letting go takes the same time as pushing: the push relaxes from where it is (a hand
            # that springs open would let a deflected arm snap back faster than any joint may move).
            self.across = None
            self.force -= self.follow * self.force
            self.torque -= self.follow * self.torque
            if _norm(self.force) < RELEASED and _norm(self.torque) < RELEASED * LEVER:
                self.force[:] = 0.0
                self.torque[:] = 0.0
                return None
            return (
                _saturate(self.force + tremor[:3], p.max_force),
                _saturate(self.torque + LEVER * tremor[3:], p.max_torque),
            )
        if self.across is None:
            self.across = self.aim_rng.normal(0.0, 1.0, 6)
        intended_force = p.stiffness * move[:3]
        intended_torque = p.rotational_stiffness * move[3:]
        # The off-axis part is a direction error of the push the person applies, so it scales with
        # what they are willing to apply of the wished move (a large twist capped at max_torque
        # comes with a grip force of off_axis × max_torque / LEVER, not off_axis × the whole wish).
        size = (
            _norm(_saturate(intended_force, p.max_force))
            + _norm(_saturate(intended_torque, p.max_torque)) / LEVER
        )
        # A part of the move within rounding of nothing (a task that only tilts the cup, or only
        # moves it) has no direction: the off-axis push then goes along the bout's own direction,
        # not across one that rounding made up (which would flip with the last bit of the pose).
        negligible = NEGLIGIBLE * size
        along_force = intended_force if _norm(intended_force) > negligible else np.zeros(3)
        along_torque = intended_torque if _norm(intended_torque) / LEVER > negligible else np.zeros(3)
        # The arm's spring pulls by the wished move and the lag together, capped as one pull; the
        # off-axis part rides on it, and the whole push is capped again.
        pull_force, pull_torque = intended_force, intended_torque
        if lag is not None:
            pull_force = pull_force + p.stiffness * lag[:3]
            pull_torque = pull_torque + p.rotational_stiffness * lag[3:]
        stray_force = p.off_axis * size * _across(self.across[:3], along_force)
        stray_torque = p.off_axis * size * LEVER * _across(self.across[3:], along_torque)
        wished_force = _saturate(_saturate(pull_force, p.max_force) + stray_force, p.max_force)
        wished_torque = _saturate(_saturate(pull_torque, p.max_torque) + stray_torque, p.max_torque)
        self.force += self.follow * (wished_force - self.force)
        self.torque += self.follow * (wished_torque - self.torque)
        return (
            _saturate(self.force + tremor[:3], p.max_force),
            _saturate(self.torque + LEVER * tremor[3:], p.max_torque),
        )


def _norm(v: np.ndarray) -> float:
    return math.sqrt(float(v @ v))
