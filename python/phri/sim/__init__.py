"""Simulation of the study: the JACO2 (natively, or in PyBullet), the simulated participant, and episodes."""

from phri.sim.episode import (
    LATER_THRESHOLDS,
    ORIGINAL_THRESHOLDS,
    SIMULATORS,
    STRATEGIES,
    EpisodeConfig,
    EpisodeResult,
    Planner,
    run_episode,
)
from phri.sim.participant import Participant, ParticipantParams, Population, load_population
from phri.sim.world import World, WorldParams

__all__ = [
    "LATER_THRESHOLDS",
    "ORIGINAL_THRESHOLDS",
    "SIMULATORS",
    "STRATEGIES",
    "EpisodeConfig",
    "EpisodeResult",
    "Participant",
    "ParticipantParams",
    "Population",
    "Planner",
    "World",
    "WorldParams",
    "load_population",
    "run_episode",
]
