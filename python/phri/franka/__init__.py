"""phri on a Franka (FR3 / Panda) over libfranka: the backend (``phri[franka]``) and a franky-sim
server that speaks the same protocol in simulation (``phri[franka-sim]``)."""

from phri.franka.backend import CollisionThresholds, FrankaBackend, fault_message

__all__ = ["CollisionThresholds", "FrankaBackend", "fault_message"]
