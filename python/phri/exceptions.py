"""The exceptions phri raises.

Every error about an argument is both a :class:`PhriError` and a :class:`ValueError`, so callers can
catch the specific case (``except ShapeError``), everything from phri (``except PhriError``), or keep
their usual ``except ValueError``. Messages name the argument and what was expected.
"""

from __future__ import annotations

__all__ = [
    "ConfigError",
    "ConnectionLostError",
    "FeatureError",
    "InvalidParameterError",
    "LogError",
    "MissingExtraError",
    "NonFiniteError",
    "NotConvergedError",
    "PhriError",
    "PlanningError",
    "ReplanWorkerError",
    "RobotFaultError",
    "SafetyStopError",
    "ShapeError",
    "SimulationError",
    "UnknownNameError",
    "UrdfError",
]


class PhriError(Exception):
    """Base class of every error phri raises on purpose."""


class ShapeError(PhriError, ValueError):
    """An array has the wrong shape, e.g. ``q must have shape (7,), got (6,)``."""


class NonFiniteError(PhriError, ValueError):
    """An input holds NaN or infinity where a finite number is required."""


class InvalidParameterError(PhriError, ValueError):
    """A parameter is outside its allowed range (negative window, zero step, bounds crossed, ...)."""


class UnknownNameError(PhriError, ValueError):
    """A frame, joint, feature or task name that is not known; the message lists the known ones."""


class UrdfError(PhriError, ValueError):
    """A robot description that is missing, malformed, or does not describe a usable chain."""


class ConfigError(PhriError, ValueError):
    """A task, study or simulation file with a missing key or a wrong value (names file and key)."""


class FeatureError(PhriError, ValueError):
    """A feature defined outside phri's core (in Python) failed: it raised, returned the wrong shape
    or a non-finite value, or took longer than its ``timeout``. The message names the feature."""


class PlanningError(PhriError, ValueError):
    """A task that cannot be planned as asked: its goal too far from its start for its duration at the
    allowed joint speeds, or its clearance above the table out of reach."""


class ReplanWorkerError(PhriError, RuntimeError):
    """The learner's replan worker thread failed: a panic inside phri (a bug to report, with the
    message) or a worker that stopped. Raised once, by the next ``Learner.observe``; the arm kept
    the plan it was tracking and the learner goes on (later corrections replan again)."""


class LogError(PhriError, ValueError):
    """A file given as an episode log (or a study folder) that cannot be read, or is not one phri
    wrote: not a .npz, damaged, or missing the arrays a replay needs. The message names the file."""


class MissingExtraError(PhriError, ImportError):
    """An optional dependency is not installed; the message names the ``pip install 'phri[...]'``
    that installs it (e.g. ``phri[sim]`` for PyBullet). ``import phri`` and the core API need numpy
    only."""


class NotConvergedError(PhriError, RuntimeError):
    """An iterative solver stopped without meeting its tolerance."""


class SimulationError(PhriError, RuntimeError):
    """The simulation produced an invalid state (e.g. NaN); logs written so far stay readable."""


class ConnectionLostError(PhriError, ConnectionError):
    """A server phri talks to does not answer: the robot (or the simulator serving its protocol), or
    a Ray cluster. Nothing accepted the connection within its timeout, or the robot sent no state for
    longer than the loop tolerates mid-episode."""


class RobotFaultError(PhriError, RuntimeError):
    """The robot reported its own reflex or error state (e.g. a collision reflex, a joint limit
    hit); the message names the state and the recovery to do (e.g. ``automatic_error_recovery``)."""


class SafetyStopError(PhriError, RuntimeError):
    """phri's safety layer or watchdog stopped the arm (it then held its position): a non-finite
    value, a limit violated, a lost connection, late ticks or a robot fault. ``event`` holds the
    reason and the state that caused it, as logged."""

    def __init__(self, message: str, event: object = None) -> None:
        super().__init__(message)
        self.event = event
