"""phri: robots that learn what a person wants from being pushed.

Reference implementation of Bajcsy, Losey, O'Malley and Dragan, "Learning Robot Objectives from
Physical Human Interaction" (CoRL 2017), with a Rust core. Units are SI: m, rad, s, kg, N, N·m.
"""

from __future__ import annotations

import logging

from phri import exceptions
from phri._phri import (
    BETA_FULL,
    BETA_MAX,
    BETA_THRESHOLD,
    DEFAULT_EFFORT,
    Deformation,
    Features,
    ImpedanceController,
    InteractionDetector,
    Learner,
    PlanLevels,
    Robot,
    Scene,
    SceneObject,
    SimulatedArm,
    SimulatedLoop,
    TimedTrajectory,
    TrajectoryOptimizer,
    TrajoptInfo,
    UpdateInfo,
    WeightUpdate,
    __version__,
    rationality,
    relevance,
)
from phri.config import Task, load_task, task_names
from phri.feature import Feature, feature

# phri logs to the "phri" logger tree and leaves where it goes to the application (the CLI: stderr).
logging.getLogger(__name__).addHandler(logging.NullHandler())

__all__ = [
    "BETA_FULL",
    "BETA_MAX",
    "BETA_THRESHOLD",
    "DEFAULT_EFFORT",
    "Deformation",
    "Feature",
    "Features",
    "ImpedanceController",
    "InteractionDetector",
    "Learner",
    "PlanLevels",
    "Robot",
    "Scene",
    "SceneObject",
    "SimulatedArm",
    "SimulatedLoop",
    "TimedTrajectory",
    "TrajectoryOptimizer",
    "TrajoptInfo",
    "UpdateInfo",
    "WeightUpdate",
    "Task",
    "__version__",
    "exceptions",
    "feature",
    "load_task",
    "task_names",
    "rationality",
    "relevance",
]
