"""The study protocol (paper §4.1): who does what, in which order, with which random numbers.

P simulated participants, within subjects: every participant uses every strategy. The order of the
strategies is counterbalanced (a Latin square: participant p starts with strategy p mod k). Per
strategy a participant does the familiarization task and then tasks 1-3, each attempted twice.

Every random number is derived from the study seed with :class:`numpy.random.SeedSequence`, keyed by
what it is for, never by when it is drawn: participant p's parameters from
``(seed, 0, p, crc32(parameter))`` (quantiles of the study's population), and an episode's seed
from ``(seed, 1, p, crc32(strategy), crc32(task), attempt)``. So results do not depend on execution
order, on the backend, or on which other tasks the study contains.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import zlib
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from phri._validate import finite, is_integer, must_be, parse_toml
from phri.config import STUDY_TASKS, Task, knots_expected, knots_fit, load_task, task_names
from phri.exceptions import ConfigError, UnknownNameError
from phri.sim.episode import STRATEGIES, EpisodeConfig
from phri.sim.participant import ParticipantParams, Population, default_population, load_population
from phri.study.errors import StudyConfigError

__all__ = [
    "MAX_ATTEMPTS",
    "MAX_PARTICIPANTS",
    "EpisodeSpec",
    "StudyConfig",
    "episode_seed",
    "participant_params",
    "schedule",
    "strategy_order",
]

_EPISODE_KEY = 1


#: Most participants and attempts a study may have: beyond them, scheduling alone would take
#: minutes before anything happened. 10,000 participants × 2 attempts × 4 tasks ×
#: 2 strategies is 160,000 episodes, about 17 hours on 2 cores; run bigger designs as several studies.
MAX_PARTICIPANTS = 10_000
#: Most attempts per task and strategy a study may have (see MAX_PARTICIPANTS).
MAX_ATTEMPTS = 100

#: StudyConfig's fields that say how the study runs, not what it is: neither saved nor compared.
_EXECUTION = frozenset({"folder", "simulator"})
#: The folder of a study folder that keeps copies of the task files it was started with (tasks
#: given as paths), named ``<task name>.toml``: the study is resumed and reported from them,
#: wherever it is run from and wherever the original files went.
TASKS_FOLDER = "tasks"


@dataclass(frozen=True)
class StudyConfig:
    """Everything that defines a study's results. Two runs with equal configs give equal tables.

    Execution settings (backend, workers, progress bar) are not part of it."""

    #: Number of simulated participants (the paper: 10).
    participants: int = 10
    #: Attempts per task and strategy (the paper: 2).
    attempts: int = 2
    #: Study seed (a non-negative integer).
    seed: int = 0
    #: Tasks in the order a participant does them: shipped names or paths of task TOML files.
    tasks: tuple[str, ...] = STUDY_TASKS
    #: The task that only familiarizes (left out of the pooled ANOVA); None: every task counts.
    familiarization: str | None = "human"
    #: Strategies compared (within subjects, order counterbalanced).
    strategies: tuple[str, ...] = STRATEGIES
    #: Override of every task's duration [s] (None: the task file's; the study's is 15 s).
    duration: float | None = None
    #: Override of every task's number of plan waypoints (None: the task file's).
    waypoints: int | None = None
    #: Override of every task's plan knots (Task.knots; 0 plans every waypoint; None: the task
    #: file's).
    knots: int | None = None
    #: Rate at which the robot samples the person's torque [Hz] (EpisodeConfig.sample_rate).
    sample_rate: float = 10.0
    #: Gaussian noise on the joint-torque measurement [N·m] (EpisodeConfig.sensor_noise).
    sensor_noise: float = 0.1
    #: Weight-update rule: "all" (the paper), "max", "confidence" or "beta" (EpisodeConfig.rule).
    rule: str = "all"
    #: Risk-aware planning: each learned weight planned k belief standard deviations above its
    #: estimate (EpisodeConfig.risk); 0 plans with the estimate, as the paper.
    risk: float = 0.0
    #: Who the simulated participants are: their parameters' distributions (a population file's
    #: contents; the study keeps them, so a resumed study draws the same people).
    population: Population = field(default_factory=default_population)
    #: Not a study parameter (neither compared nor saved): the study folder this config was read
    #: from or runs into. With it, tasks given as paths name that folder's copies
    #: (``tasks/<name>.toml``, see :data:`TASKS_FOLDER`) and nothing outside it; without, paths are
    #: read as given (relative to the working directory).
    folder: Path | None = dataclasses.field(default=None, compare=False, repr=False)
    #: Not a study parameter either (neither compared nor saved): what simulates the episodes
    #: (EpisodeConfig.simulator: "native", or "pybullet"; the two agree within docs/simulation.md's
    #: tolerance, so a study may be resumed on either).
    simulator: str = dataclasses.field(default="native", compare=False, repr=False)

    def __post_init__(self) -> None:
        def fail(key: str, expected: str, got: Any) -> Exception:
            return must_be(f"study: {key}", expected, got, error=StudyConfigError)

        integer = is_integer
        if not integer(self.participants) or not 1 <= self.participants <= MAX_PARTICIPANTS:
            raise fail("participants", f"an integer in [1, {MAX_PARTICIPANTS}]", self.participants)
        if not integer(self.attempts) or not 1 <= self.attempts <= MAX_ATTEMPTS:
            raise fail("attempts", f"an integer in [1, {MAX_ATTEMPTS}]", self.attempts)
        if not integer(self.seed) or self.seed < 0:
            raise fail("seed", "an integer >= 0", self.seed)
        object.__setattr__(self, "participants", int(self.participants))
        object.__setattr__(self, "attempts", int(self.attempts))
        object.__setattr__(self, "seed", int(self.seed))
        for key in ("tasks", "strategies"):
            value = getattr(self, key)
            if isinstance(value, str) or not all(isinstance(x, str) and x for x in value) or not value:
                raise fail(key, "a non-empty list of names", value)
            if len(set(value)) != len(value):
                raise fail(key, "a list without repeats", value)
            object.__setattr__(self, key, tuple(str(x) for x in value))
        for s in self.strategies:
            if s not in STRATEGIES:
                raise fail("strategies", f"a list of {STRATEGIES}", self.strategies)
        paths = any(_is_path(t) for t in self.tasks)  # names known once loaded: checked in load_tasks
        unknown = [t for t in self.tasks if not _is_path(t) and t not in task_names()]
        if unknown:
            raise fail(
                "tasks",
                f"shipped task names ({', '.join(task_names())}) or paths of task TOML files",
                unknown,
            )
        if self.familiarization is not None and not paths and self.familiarization not in self.tasks:
            raise fail(
                "familiarization",
                f"one of the study's tasks {list(self.tasks)} or none",
                self.familiarization,
            )
        if self.duration is not None:
            if not (finite(self.duration) and self.duration > 0):
                raise fail("duration", "a number of seconds > 0 or none", self.duration)
            object.__setattr__(self, "duration", float(self.duration))
        if self.waypoints is not None and (not integer(self.waypoints) or self.waypoints < 3):
            raise fail("waypoints", "an integer >= 3 or none", self.waypoints)
        if self.knots is not None and (not integer(self.knots) or self.knots in (1, 2) or self.knots < 0):
            raise fail("knots", "0 (plan every waypoint), an integer >= 3 or none", self.knots)
        for key in ("sample_rate", "sensor_noise", "risk"):
            v = getattr(self, key)
            if not finite(v):
                raise fail(key, "a finite number", v)
            object.__setattr__(self, key, float(v))
        for key in ("waypoints", "knots"):
            if getattr(self, key) is not None:
                object.__setattr__(self, key, int(getattr(self, key)))
        try:
            EpisodeConfig(
                sample_rate=self.sample_rate, sensor_noise=self.sensor_noise, rule=self.rule,
                risk=self.risk, simulator=self.simulator,
            )  # fmt: skip
        except ValueError as e:
            raise StudyConfigError(f"study: {e}") from None
        if not isinstance(self.population, Population):  # a name, a path or a table (as to_dict gives)
            object.__setattr__(self, "population", _population(self.population, "study", None))

    # -- the study's parts ------------------------------------------------------------------------

    def episode_config(self, strategy: str) -> EpisodeConfig:
        """How the study runs an episode of `strategy` (its sample rate, sensor noise, rule and risk)."""
        return EpisodeConfig(
            strategy=strategy, sample_rate=self.sample_rate, sensor_noise=self.sensor_noise, rule=self.rule,
            risk=self.risk, simulator=self.simulator,
        )  # fmt: skip

    def load_tasks(self) -> dict[str, Task]:
        """The study's tasks by name, with the duration/waypoints/knots overrides applied."""
        tasks: dict[str, Task] = {}
        for spec in self.tasks:
            try:
                task = load_task(self._task_source(spec))
            except (ConfigError, UnknownNameError) as e:
                raise StudyConfigError(f"study: task {spec!r}: {e}") from None
            if self.duration is not None:
                task = dataclasses.replace(task, duration=self.duration)
            if self.waypoints is not None:
                task = dataclasses.replace(task, waypoints=self.waypoints)
            if self.knots is not None:
                task = dataclasses.replace(task, knots=self.knots)
            if not knots_fit(task.knots, task.waypoints):
                raise StudyConfigError(
                    f"study: knots of task {task.name!r} must be {knots_expected(task.waypoints)}, got "
                    f"{task.knots} (knots = 0 plans every waypoint)"
                )
            if task.name in tasks:
                raise StudyConfigError(f"study: two tasks are named {task.name!r}; task names must be unique")
            tasks[task.name] = task
        if self.familiarization is not None and self.familiarization not in tasks:
            raise StudyConfigError(
                f"study: familiarization must be one of the study's tasks {list(tasks)} or none, "
                f"got {self.familiarization!r}"
            )
        return tasks

    def _task_source(self, spec: str) -> str:
        """What `load_task` reads for the task `spec`: in a study folder, a path must name a file in
        its :data:`TASKS_FOLDER` (a study.json naming any other file is refused)."""
        if self.folder is None or not _is_path(spec):
            return spec
        root = (self.folder / TASKS_FOLDER).resolve()
        inside = (self.folder / spec).resolve()
        if Path(spec).is_absolute() or not inside.is_relative_to(root) or inside == root:
            raise StudyConfigError(
                f"study: task {spec!r} must be a file in the study folder's {TASKS_FOLDER}/ "
                f"(e.g. '{TASKS_FOLDER}/coffee.toml'; a study keeps copies of its task files there), "
                f"in {self.folder}"
            )
        return str(inside)

    def in_folder(self, folder: str | Path) -> StudyConfig:
        """This study as the study folder `folder` keeps it: each task given as a path named by its
        copy there, ``tasks/<name>.toml`` (the copies are the caller's to write: see
        :meth:`task_files`), and read from the folder from now on."""
        loaded = self.load_tasks()
        tasks = tuple(
            f"{TASKS_FOLDER}/{task.name}.toml" if _is_path(spec) else spec
            for spec, task in zip(self.tasks, loaded.values(), strict=True)
        )
        return dataclasses.replace(self, tasks=tasks, folder=Path(folder).resolve())

    def task_files(self) -> dict[str, Path]:
        """The files of the tasks given as paths, by the name of their copy in a study folder's
        :data:`TASKS_FOLDER` (``<name>.toml``)."""
        loaded = self.load_tasks()
        files = {}
        for spec, task in zip(self.tasks, loaded.values(), strict=True):
            if _is_path(spec):
                files[f"{task.name}.toml"] = Path(task.source)
                # The Python features it names, at the same place relative to the copy.
                for code in filter(None, (f.code() for f in (*task.features, *task.unmodelled))):
                    files[code[1]] = code[0]
        return files

    def task_names(self) -> list[str]:
        """Names of the study's tasks (a file's `name` key for a task given as a path)."""
        return (
            [t.name for t in self.load_tasks().values()]
            if any(_is_path(t) for t in self.tasks)
            else list(self.tasks)
        )

    @property
    def episodes(self) -> int:
        """How many episodes the study has: participants × strategies × tasks × attempts."""
        return self.participants * len(self.strategies) * len(self.tasks) * self.attempts

    # -- serialisation ------------------------------------------------------------------------------

    def to_dict(self) -> dict[str, Any]:
        """The config as JSON-ready values (study.json's ``config``)."""
        d = {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.name not in _EXECUTION}
        d["tasks"], d["strategies"] = list(self.tasks), list(self.strategies)
        d["population"] = self.population.to_dict()
        return d

    @classmethod
    def from_dict(
        cls, data: Mapping[str, Any], source: str = "study", base_dir: Path | None = None
    ) -> StudyConfig:
        """From a mapping such as a parsed study.json or study TOML; unknown keys are errors.
        ``population`` is a shipped population's name, a population file's path (relative to
        `base_dir` if given) or a population table."""
        if not isinstance(data, Mapping):
            raise StudyConfigError(
                f"{source}: expected a table of study parameters, got {type(data).__name__}"
            )
        known = {f.name for f in dataclasses.fields(cls)} - _EXECUTION
        unknown = sorted(set(data) - known)
        if unknown:
            raise StudyConfigError(f"{source}: unknown key(s) {unknown}; known: {sorted(known)}")
        kwargs = dict(data)
        for key in ("tasks", "strategies"):
            if key in kwargs:
                if not isinstance(kwargs[key], list | tuple):
                    raise StudyConfigError(
                        f"{source}: key '{key}' must be a list of names, got {kwargs[key]!r}"
                    )
                kwargs[key] = tuple(kwargs[key])
        if kwargs.get("familiarization") == "":
            kwargs["familiarization"] = None
        if "population" in kwargs:
            kwargs["population"] = _population(kwargs["population"], source, base_dir)
        try:
            return cls(**kwargs)
        except StudyConfigError as e:
            if source == "study":
                raise
            raise StudyConfigError(str(e).replace("study: ", f"{source}: key ", 1)) from None

    @classmethod
    def from_toml(cls, path: str | Path) -> StudyConfig:
        """A study file: top-level keys as the fields of this class, e.g. ``participants = 10``.
        ``familiarization = ""`` means none."""
        path = Path(path)
        try:
            text = path.read_text(encoding="utf-8")
        except OSError as e:
            raise StudyConfigError(f"{path}: cannot read the study file ({e.strerror})") from None
        data = parse_toml(text, str(path), "a study file", StudyConfigError)
        return cls.from_dict(data, str(path), path.parent)

    def task_digests(self) -> dict[str, str]:
        """A SHA-256 per task of what the task file said (after overrides), so that a resumed
        study notices a task file that changed in between."""
        out = {}
        for name, task in self.load_tasks().items():
            d = {
                k: (v.tolist() if isinstance(v, np.ndarray) else v)
                for k, v in dataclasses.asdict(task).items()
                if k not in ("source", "scene")
            }
            if not task.knots:  # a task that plans every waypoint has the digest it had before knots
                del d["knots"]
            if not task.unmodelled:  # likewise without unmodelled features
                del d["unmodelled"]
            d["scene"] = [_scene_object_record(o) for o in task.scene.objects]
            specs = (*task.features, *task.unmodelled)
            for feature, record in zip(specs, [*d["features"], *d.get("unmodelled", [])], strict=True):
                code = feature.code()
                if code is not None:
                    # What the code says, not where it is (a study reads its folder's copy).
                    record["params"] = {k: v for k, v in record["params"].items() if k != "folder"}
                    record["params"]["code"] = hashlib.sha256(code[0].read_bytes()).hexdigest()
            if isinstance(d.get("safety"), dict) and isinstance(d["safety"].get("limits"), dict):
                # Where the file is, not what it says (a study reads its folder's copy on resume).
                d["safety"]["limits"].pop("source", None)
            out[name] = hashlib.sha256(json.dumps(d, sort_keys=True, default=str).encode()).hexdigest()
        return out


def _scene_object_record(o: Any) -> dict[str, Any]:
    """Everything a scene object says, as plain values (its digest must not hang on a repr)."""
    values = {key: getattr(o, key) for key in ("name", "shape", "kind", "margin", "radius", "length")}
    for key in ("position", "size", "rpy"):
        v = getattr(o, key)
        values[key] = None if v is None else [float(x) for x in v]
    return values


def _population(value: Any, source: str, base_dir: Path | None) -> Population:
    """The study's `population` key: a name, a path or a table (errors name the study's source)."""
    where = "study: population" if source == "study" else f"{source}: key 'population'"
    if isinstance(value, Population):
        return value
    try:
        if isinstance(value, str | Path):
            path = Path(value)
            if base_dir is not None and _is_path(str(value)) and not path.is_absolute():
                path = base_dir / path
            return load_population(path if _is_path(str(value)) else str(value))
        if isinstance(value, Mapping):
            return Population.from_dict(value, where)
    except (ConfigError, UnknownNameError) as e:
        raise StudyConfigError(str(e) if isinstance(value, Mapping) else f"{where}: {e}") from None
    raise StudyConfigError(f"{where} must be a population name, a file path or a table, got {value!r}")


def _is_path(spec: str) -> bool:
    return spec.endswith(".toml") or "/" in spec or "\\" in spec


@dataclass(frozen=True, order=True)
class EpisodeSpec:
    """One attempt of one participant at one task with one strategy."""

    #: Position in the study's session order (participant, order, task, attempt).
    index: int
    #: 1-based participant number.
    participant: int
    strategy: str
    #: 1-based position of this strategy in the participant's sequence (counterbalancing).
    order: int
    task: str
    #: 1-based attempt number.
    attempt: int
    seed: int

    @property
    def key(self) -> tuple[int, str, str, int]:
        """(participant, strategy, task, attempt): what identifies the episode in the results."""
        return (self.participant, self.strategy, self.task, self.attempt)

    def log_name(self, width: int = 2) -> str:
        """The file name of the episode's log, its participant number padded to `width` digits."""
        return f"p{self.participant:0{width}d}_{self.strategy}_{self.task}_a{self.attempt}.npz"


def _name_key(name: str) -> int:
    return zlib.crc32(name.encode("utf-8"))


def episode_seed(study_seed: int, participant: int, strategy: str, task: str, attempt: int) -> int:
    """The episode's seed, from what the episode is (not from when it runs)."""
    ss = np.random.SeedSequence(
        study_seed, spawn_key=(_EPISODE_KEY, participant, _name_key(strategy), _name_key(task), attempt)
    )
    return int(ss.generate_state(1, dtype=np.uint64)[0] >> np.uint64(1))  # 63 bits: fits an int64 column


def participant_params(
    study_seed: int, participant: int, population: Population | None = None
) -> ParticipantParams:
    """Participant `participant`'s (1-based) simulated behaviour, drawn from `population` (default:
    phri's default population) with the study seed: per parameter a uniform number keyed by
    ``(seed, 0, participant, crc32(parameter))`` (Population.draw), so the same seed gives the same
    person under every strategy, and the same quantiles in every population."""
    return (population or default_population()).draw(study_seed, participant)


def strategy_order(config: StudyConfig, participant: int) -> tuple[str, ...]:
    """Counterbalanced order (a Latin square over the strategies): participant 1 starts with the
    first strategy, participant 2 with the second, and so on cyclically."""
    k = len(config.strategies)
    shift = (participant - 1) % k
    return config.strategies[shift:] + config.strategies[:shift]


def schedule(config: StudyConfig) -> list[EpisodeSpec]:
    """Every episode of the study in session order."""
    return list(_iter_schedule(config, config.task_names()))


def _iter_schedule(config: StudyConfig, tasks: list[str]) -> Iterator[EpisodeSpec]:
    index = 0
    for p in range(1, config.participants + 1):
        for order, strategy in enumerate(strategy_order(config, p), start=1):
            for task in tasks:
                for attempt in range(1, config.attempts + 1):
                    seed = episode_seed(config.seed, p, strategy, task, attempt)
                    yield EpisodeSpec(index, p, strategy, order, task, attempt, seed)
                    index += 1
