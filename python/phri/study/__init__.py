"""The user study (paper §4): protocol, parallel execution, results, statistics, figures, report and
the Table 1 questionnaire.

``run_study(folder)`` runs the simulated study (10 participants × 2 strategies × 4 tasks × 2 attempts)
into a folder and resumes it when run again; ``write_report(folder)`` analyses it.
"""

from __future__ import annotations

from phri.study.errors import (
    QuestionnaireError,
    StudyConfigError,
    StudyError,
    StudyFileError,
    StudyLockedError,
    StudyMismatchError,
)
from phri.study.protocol import (
    EpisodeSpec,
    StudyConfig,
    episode_seed,
    participant_params,
    schedule,
    strategy_order,
)
from phri.study.results import COLUMNS, ResultStore, load_results, read_manifest
from phri.study.run import StudyRun, run_study

__all__ = [
    "COLUMNS",
    "EpisodeSpec",
    "QuestionnaireError",
    "ResultStore",
    "StudyConfig",
    "StudyConfigError",
    "StudyError",
    "StudyFileError",
    "StudyLockedError",
    "StudyMismatchError",
    "StudyRun",
    "episode_seed",
    "load_results",
    "participant_params",
    "read_manifest",
    "run_study",
    "schedule",
    "strategy_order",
    "write_report",
]


def __getattr__(name: str) -> object:
    # The report pulls in pandas, statsmodels and matplotlib: imported when first asked for.
    if name == "write_report":
        from phri.study.report import write_report

        return write_report
    raise AttributeError(f"module 'phri.study' has no attribute {name!r}")
