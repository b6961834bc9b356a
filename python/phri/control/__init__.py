"""phri's control loop for simulation and hardware, behind one backend interface
(:class:`phri.control.backend.Backend`)."""

from phri.control.backend import Backend, RobotState

__all__ = ["Backend", "RobotState"]
