"""Simulation of the study: the JACO2 in PyBullet, the simulated participant, and episodes."""

from phri.sim.episode import (
    LATER_THRESHOLDS,
    ORIGINAL_THRESHOLDS,
    STRATEGIES,
    EpisodeConfig,
    EpisodeResult,
    Planner,
    run_episode,
)
from phri.sim.participant import DISTRIBUTIONS, Participant, ParticipantParams
from phri.sim.world import World, WorldParams

__all__ = [
    "DISTRIBUTIONS",
    "LATER_THRESHOLDS",
    "ORIGINAL_THRESHOLDS",
    "STRATEGIES",
    "EpisodeConfig",
    "EpisodeResult",
    "Participant",
    "ParticipantParams",
    "Planner",
    "World",
    "WorldParams",
    "run_episode",
]
