"""phri's control loop for simulation and hardware, behind one backend interface
(:class:`phri.control.backend.Backend`), with its safety layer and watchdog.

- :class:`ControlLoop` runs a motion over a backend: read, observe, reference, impedance torque,
  safety checks, write; it stops the arm (holds, then ends the motion) on a violation, a lost
  connection or the robot's fault, and records every stop (:class:`StopEvent`).
- :func:`safety_limits` reads the safety layer's limits from the robot description's and the
  task's ``[safety]`` tables; :class:`SafetyLayer` (Rust) checks them every tick.
"""

from phri._phri import SAFETY_LIMITS, SafetyLayer, SafetyViolation
from phri.control.backend import Backend, RobotState
from phri.control.loop import HOLD_TIME, LOG_RATE, STOP_REASONS, ControlLoop, LoopResult, StopEvent
from phri.control.safety import LATE_AFTER, LATE_TICKS, SafetyLimits, safety_limits

__all__ = [
    "HOLD_TIME",
    "LATE_AFTER",
    "LATE_TICKS",
    "LOG_RATE",
    "SAFETY_LIMITS",
    "STOP_REASONS",
    "Backend",
    "ControlLoop",
    "LoopResult",
    "RobotState",
    "SafetyLayer",
    "SafetyLimits",
    "SafetyViolation",
    "StopEvent",
    "safety_limits",
]
