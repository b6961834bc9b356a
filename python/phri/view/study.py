"""The episodes of a study folder (``phri study``'s results.csv and logs/), as the viewer picks them:
by participant, task, strategy and attempt. Reads the table with the standard library, so viewing
needs neither pandas nor the study's extras."""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

from phri.exceptions import LogError

__all__ = ["StudyEpisode", "select", "study_episodes"]

RESULTS = "results.csv"


@dataclass(frozen=True)
class StudyEpisode:
    """One row of a study's results table that has a log."""

    participant: int
    task: str
    strategy: str
    attempt: int
    status: str
    log: Path  # absolute

    @property
    def name(self) -> str:
        """The episode's name in links and titles (its log's stem)."""
        return self.log.stem

    @property
    def title(self) -> str:
        """How the episode is named on its page: participant, task, strategy and attempt."""
        return f"participant {self.participant} · {self.task} · {self.strategy} · attempt {self.attempt}"


def study_episodes(folder: Path) -> list[StudyEpisode]:
    """The episodes of the study in `folder` whose log exists, in the table's order. A folder without
    a readable results.csv is a LogError naming it."""
    path = folder / RESULTS
    if not path.is_file():
        raise LogError(f"{folder}: not a study folder (no {RESULTS}) and not an episode log")
    try:
        with path.open(encoding="utf-8", newline="") as f:
            rows = list(csv.DictReader(f))
    except (OSError, UnicodeDecodeError, csv.Error) as e:
        raise LogError(f"{path}: cannot read the results table ({e})") from None
    episodes = []
    for i, row in enumerate(rows, start=2):
        try:
            log = folder / row["log"]
            episode = StudyEpisode(
                int(row["participant"]), row["task"], row["strategy"], int(row["attempt"]),
                row.get("status", ""), log.resolve(),
            )  # fmt: skip
        except (KeyError, TypeError, ValueError) as e:
            raise LogError(f"{path}: line {i} is not a row of a study's results table ({e})") from None
        if row["log"] and log.is_file():
            episodes.append(episode)
    return episodes


def select(
    episodes: list[StudyEpisode],
    *,
    participant: int | None = None,
    task: str | None = None,
    strategy: str | None = None,
    attempt: int | None = None,
) -> list[StudyEpisode]:
    """The `episodes` that match every choice given (None: any)."""
    return [
        e for e in episodes
        if (participant is None or e.participant == participant) and (task is None or e.task == task)
        and (strategy is None or e.strategy == strategy) and (attempt is None or e.attempt == attempt)
    ]  # fmt: skip
