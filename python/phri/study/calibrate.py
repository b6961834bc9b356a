"""``phri calibrate``: fits a population of simulated participants to reference statistics.

Given targets (:mod:`phri.study.targets`: per task and strategy the mean effort, interaction time and
effort per sample, optional SDs, optional pooled F values), it searches the population's free
quantities — by default the medians of the push levels, the off-axis push, the patience and the hold,
and a common scale of every spread — for the population whose simulated study matches them best.

- **Cheap candidates.** Each candidate is a small simulated study: ``participants`` people × the
  targets' tasks × both strategies × ``attempts`` (default 5 × 2 × 2 × 1 = 20 episodes), in a pool of
  ``workers`` processes that keep their simulator and plans between candidates.
- **Common random numbers.** Every candidate sees the same people (the same quantiles of each
  parameter, :meth:`phri.sim.participant.Population.draw`) and the same episode seeds, so two
  candidates differ only by their parameters, and the search is not misled by sampling noise.
- **The optimiser** is scipy's Nelder–Mead (derivative-free, which the simulated study needs) on the
  logarithms of the free quantities, for at most ``budget`` candidates.
- **The loss** is the mean squared log-ratio of simulated to target statistics (each mean, each SD at
  half weight, and each pooled F as the effect size it implies, partial η² = F / (F + df), matched on
  the calibrated tasks' trials at half weight).

A calibration that misses a target by more than ``tolerance`` (relative) says which, and by how much,
and :func:`write_population` refuses to write it unless asked to (``accept_misses``).
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from phri._extras import require
from phri.atomic import write_atomic
from phri.config import Task, load_task
from phri.exceptions import InvalidParameterError, PhriError
from phri.sim.episode import SIMULATORS, STRATEGIES, EpisodeConfig, Planner, simulate_episode
from phri.sim.participant import PARAMETERS, Population, default_population
from phri.sim.participant.population import start_record
from phri.sim.world import World
from phri.study.protocol import episode_seed
from phri.study.targets import PooledTest, Targets, compare

if TYPE_CHECKING:
    import pandas as pd
else:
    pd = require("pandas", __name__)

__all__ = [
    "DEFAULT_FREE",
    "SPREAD",
    "CalibrationError",
    "CalibrationResult",
    "CalibrationSettings",
    "calibrate",
    "write_population",
]

logger = logging.getLogger(__name__)

#: The free quantity that scales every distribution's spread (lognormal sigma, normal sd).
SPREAD = "spread"
#: What a calibration fits unless told otherwise: ``parameter.key`` of a distribution, or SPREAD.
DEFAULT_FREE = (
    "max_force.median",
    "max_torque.median",
    "off_axis.median",
    "patience.median",
    "hold.median",
    SPREAD,
)
#: Simulated statistics are floored here before their logarithm is taken (a 0 would be -inf).
_FLOOR = 1e-3
#: First step of the search in each log-quantity (a 35 % change).
_STEP = 0.3


class CalibrationError(PhriError, ValueError):
    """A calibration that cannot run, or whose result misses its targets."""


class _OutOfBudget(Exception):
    """Stops the search once it has evaluated its budget of candidates."""


@dataclass(frozen=True)
class CalibrationSettings:
    """How much simulation a calibration spends, and what it fits."""

    #: Simulated participants per candidate (common to every candidate).
    participants: int = 5
    #: Attempts per task and strategy per candidate.
    attempts: int = 1
    #: Seed of the people and of the episodes.
    seed: int = 0
    #: Most candidates evaluated.
    budget: int = 80
    #: Free quantities: "parameter.key" of a distribution (e.g. "max_force.median") or "spread".
    free: tuple[str, ...] = DEFAULT_FREE
    #: A target counts as met within this relative difference.
    tolerance: float = 0.2
    #: Worker processes (1: in this process).
    workers: int = 1
    #: What simulates the episodes (EpisodeConfig.simulator): "native" or "pybullet".
    simulator: str = "native"

    def __post_init__(self) -> None:
        for key in ("participants", "attempts", "budget", "workers"):
            v = getattr(self, key)
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise InvalidParameterError(f"{key} must be an integer >= 1, got {v!r}")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or self.seed < 0:
            raise InvalidParameterError(f"seed must be an integer >= 0, got {self.seed!r}")
        if not (math.isfinite(self.tolerance) and self.tolerance > 0):
            raise InvalidParameterError(
                f"tolerance must be a relative difference > 0, got {self.tolerance!r}"
            )
        if not self.free:
            raise InvalidParameterError("free must name at least one quantity to fit")
        if self.simulator not in SIMULATORS:
            raise InvalidParameterError(f"simulator must be one of {SIMULATORS}, got {self.simulator!r}")


@dataclass
class Candidate:
    """One evaluated population: its statistics against the targets and its loss."""

    population: Population
    comparison: list[dict[str, Any]]
    loss: float


@dataclass
class CalibrationResult:
    """What a calibration found."""

    population: Population
    best: Candidate
    start: Candidate
    evaluations: int
    elapsed: float
    tolerance: float
    settings: CalibrationSettings
    targets: Targets
    history: list[float] = field(default_factory=list)
    #: The population the search started from, as given (the first candidate clips values at their
    #: parameters' bounds); None: :attr:`start`'s.
    initial: Population | None = None

    @property
    def misses(self) -> list[dict[str, Any]]:
        """The targets the best population misses by more than the tolerance."""
        return [r for r in self.best.comparison if not _met(r, self.tolerance)]

    @property
    def reached(self) -> bool:
        """Whether the best population meets every target within the tolerance (no :attr:`misses`)."""
        return not self.misses

    def table(self) -> str:
        """Target against achieved, as plain text."""
        lines = [
            f"{'task':<22} {'strategy':<10} {'statistic':<34} {'target':>9} {'achieved':>9} {'ratio':>6}"
        ]
        for r in self.best.comparison:
            mark = "" if _met(r, self.tolerance) else "  MISSED"
            lines.append(
                f"{r['task']:<22} {r['strategy']:<10} {r['statistic']:<34} {r['reference']:>9.4g} "
                f"{r['simulated']:>9.4g} {r['ratio']:>6.2f}{mark}"
            )
        return "\n".join(lines)

    def miss_message(self) -> str:
        """One line naming each missed target with the achieved value, the target and the relative
        difference, and the best loss after how many candidates: what :func:`write_population` says
        when it refuses, and records in the population when the misses are accepted."""
        parts = [
            f"{r['task']}{'/' + r['strategy'] if r['strategy'] else ''} {r['statistic']}: "
            f"{r['simulated']:.4g} against {r['reference']:.4g} ({(r['ratio'] - 1) * 100:+.0f} %)"
            for r in self.misses
        ]
        return (
            f"the calibration cannot reach {len(parts)} of its targets within ±{self.tolerance * 100:.0f} % "
            f"(best loss {self.best.loss:.4g} after {self.evaluations} candidates): " + "; ".join(parts)
        )


def _met(row: Mapping[str, Any], tolerance: float) -> bool:
    ratio = row["ratio"]
    return bool(math.isfinite(ratio) and abs(ratio - 1.0) <= tolerance)


# -- simulation of a candidate ----------------------------------------------------------------------

_WORKER: dict[str, Any] = {}


def _init_worker(tasks: Mapping[str, Task]) -> None:
    _WORKER.clear()
    _WORKER["tasks"] = dict(tasks)
    _WORKER["world"] = None
    _WORKER["planners"] = {}


def _episode(job: tuple[Population, int, str, str, int, int, str]) -> dict[str, Any]:
    """One episode of a candidate study (run in a worker): its row of the results table."""
    population, participant, task_name, strategy, attempt, seed, simulator = job
    if _WORKER.get("world") is None:
        _WORKER["world"] = World()
    world, planners, task = _WORKER["world"], _WORKER["planners"], _WORKER["tasks"][task_name]
    if task_name not in planners:
        planners[task_name] = Planner(task, world)
    person = population.draw(seed, participant).for_attempt(attempt)
    episode = episode_seed(seed, participant, strategy, task_name, attempt)
    config = EpisodeConfig(strategy=strategy, simulator=simulator)
    result, error = simulate_episode(task, world, person, config, seed=episode, planner=planners[task_name])
    ok = error is None
    return {
        "participant": participant, "strategy": strategy, "task": task_name, "attempt": attempt,
        "status": "ok" if ok else "failed", "effort": result.effort if ok else math.nan,
        "interaction_time": result.interaction_time if ok else math.nan,
        "cost": result.cost if ok else math.nan, "desired_cost": result.desired_cost,
    }  # fmt: skip


class _Simulator:
    """Runs candidate studies, in this process or in a pool that keeps its simulators."""

    def __init__(self, tasks: Mapping[str, Task], workers: int) -> None:
        self.tasks = dict(tasks)
        self.pool = (
            ProcessPoolExecutor(workers, initializer=_init_worker, initargs=(self.tasks,))
            if workers > 1
            else None
        )
        if self.pool is None:
            _init_worker(self.tasks)

    def run(self, population: Population, settings: CalibrationSettings) -> pd.DataFrame:
        jobs = [
            (population, p, task, strategy, attempt, settings.seed, settings.simulator)
            for p in range(1, settings.participants + 1)
            for task in self.tasks
            for strategy in STRATEGIES
            for attempt in range(1, settings.attempts + 1)
        ]
        rows = list(self.pool.map(_episode, jobs)) if self.pool is not None else [_episode(j) for j in jobs]
        from phri.study import analysis

        return analysis.prepare(pd.DataFrame(rows))

    def close(self) -> None:
        if self.pool is not None:
            self.pool.shutdown(cancel_futures=True)
        elif _WORKER.get("world") is not None:
            _WORKER["world"].close()
            _WORKER.clear()


# -- the search ---------------------------------------------------------------------------------------


def _loss(comparison: Sequence[Mapping[str, Any]]) -> float:
    """Mean squared log-ratio of simulated to target statistics (SDs and effect sizes at half weight)."""
    terms, weights = [], []
    for r in comparison:
        ref, sim = float(r["reference"]), float(r["simulated"])
        sim = sim if math.isfinite(sim) else 0.0
        terms.append(math.log(max(sim, _FLOOR * ref) / ref) ** 2)
        weights.append(0.5 if r["statistic"].endswith("_sd") or r.get("effect_size") else 1.0)
    return float(np.average(terms, weights=weights))


def _quantities(population: Population, free: Sequence[str]) -> list[tuple[str, str, float]]:
    """(parameter, key, starting value) of each free quantity; SPREAD is ("spread", "", 1.0)."""
    out = []
    for q in free:
        if q == SPREAD:
            out.append((SPREAD, "", 1.0))
            continue
        name, _, key = q.partition(".")
        if name not in PARAMETERS:
            raise CalibrationError(
                f"free: unknown parameter {name!r} in {q!r}; known: {', '.join(PARAMETERS)}"
            )
        value = population[name].get(key)
        if value is None:
            keys = [k for k, _ in population[name].values]
            raise CalibrationError(
                f"free: {q!r}: the population's {name} is a {population[name].kind} distribution with "
                f"{', '.join(keys) or 'no values'}; free a key it has"
            )
        if not value > 0:
            raise CalibrationError(f"free: {q!r} starts at {value:g}; only positive quantities can be fitted")
        out.append((name, key, float(value)))
    return out


def _candidate_population(
    start: Population, quantities: Sequence[tuple[str, str, float]], x: np.ndarray
) -> Population:
    changes: dict[tuple[str, str], float] = {}
    scale = 1.0
    for (name, key, value), xi in zip(quantities, x, strict=True):
        if name == SPREAD:
            scale = math.exp(float(xi))
            continue
        v = value * math.exp(float(xi))
        spec = PARAMETERS[name]
        if key in ("median", "mean", "value", "low", "high") and math.isfinite(spec.high):
            v = min(v, spec.high * (0.999 if spec.below else 1.0))
        changes[(name, key)] = v
    if scale != 1.0:
        for name, d in start.distributions:
            for key in ("sigma", "sd"):
                if key in dict(d.values):
                    changes[(name, key)] = dict(d.values)[key] * scale
    return start.replace(changes)


def calibrate(
    targets: Targets,
    population: Population | None = None,
    settings: CalibrationSettings | None = None,
    *,
    tasks: Mapping[str, Task] | None = None,
    progress: bool = True,
    on_candidate: Callable[[int, Candidate], None] | None = None,
) -> CalibrationResult:
    """Fits `population` (default: phri's default population, as the starting point) to `targets`.

    `tasks` maps the targets' task names to tasks (default: the shipped tasks of those names); every
    task the targets name must be there. Returns the best candidate found, whether or not it reaches
    the targets (see :attr:`CalibrationResult.misses`)."""
    minimize = require("scipy.optimize", __name__).minimize
    settings = settings or CalibrationSettings()
    start = population or default_population()
    names = targets.tasks
    if tasks is None:
        try:
            tasks = {name: load_task(name) for name in names}
        except PhriError as e:
            raise CalibrationError(f"{targets.source}: {e}") from None
    targets.check_tasks(list(tasks), "the tasks to simulate", pooled=False)
    for test in targets.pooled:
        if not set(test.tasks) & set(names):
            raise CalibrationError(
                f"{targets.source}: the pooled test over {'+'.join(test.tasks)} shares no task with the "
                f"calibrated tasks {names}"
            )
    quantities = _quantities(start, settings.free)
    tasks = {name: tasks[name] for name in names}
    simulator = _Simulator(tasks, settings.workers)
    tqdm = require("tqdm", __name__).tqdm
    bar = tqdm(total=settings.budget, desc="calibrate", unit="candidate", disable=None if progress else True,
               dynamic_ncols=True)  # fmt: skip
    evaluated: list[Candidate] = []
    seen: dict[tuple[float, ...], float] = {}
    began = time.perf_counter()

    def evaluate(x: np.ndarray) -> float:
        key = tuple(np.round(x, 9))
        if key in seen:  # Nelder-Mead re-evaluates its starting point: simulate each candidate once
            return seen[key]
        if len(evaluated) >= settings.budget:
            raise _OutOfBudget
        try:
            candidate_pop = _candidate_population(start, quantities, x)
        except PhriError:
            return 1e6  # outside what a population may be (e.g. a bound): a wall for the search
        data = simulator.run(candidate_pop, settings)
        comparison = _compare(targets, data, names)
        candidate = Candidate(candidate_pop, comparison, _loss(comparison))
        evaluated.append(candidate)
        bar.update(1)
        bar.set_postfix(loss=f"{candidate.loss:.4g}", best=f"{evaluated_best().loss:.4g}")
        if on_candidate is not None:
            on_candidate(len(evaluated), candidate)
        seen[key] = candidate.loss
        logger.info(
            "candidate %d: loss %.4g (best %.4g) at %s",
            len(evaluated), candidate.loss, evaluated_best().loss,
            ", ".join(f"{n}{'.' + k if k else ''} = {v * math.exp(float(xi)):.4g}"
                      for (n, k, v), xi in zip(quantities, x, strict=True)),
        )  # fmt: skip
        return candidate.loss

    def evaluated_best() -> Candidate:
        return min(evaluated, key=lambda c: c.loss)

    try:
        x0 = np.zeros(len(quantities))
        evaluate(x0)
        simplex = np.vstack([x0, x0 + _STEP * np.eye(len(quantities))])
        try:
            # Nelder-Mead re-visits points (cached above): it stops at the budget of new candidates,
            # or once its simplex has shrunk to 2 % in every log-quantity.
            minimize(evaluate, x0, method="Nelder-Mead",
                     options={"initial_simplex": simplex, "maxfev": 10 * settings.budget, "xatol": 0.02,
                              "fatol": 1e-4})  # fmt: skip
        except _OutOfBudget:
            pass
    finally:
        bar.close()
        simulator.close()
    best = evaluated_best()
    return CalibrationResult(
        best.population, best, evaluated[0], len(evaluated), time.perf_counter() - began,
        settings.tolerance, settings, targets, [c.loss for c in evaluated], start,
    )  # fmt: skip


def _compare(targets: Targets, data: pd.DataFrame, names: Sequence[str]) -> list[dict[str, Any]]:
    """Target against simulated for each statistic; a pooled F (over a different number of trials
    here) becomes the effect size it implies, partial η² = F / (F + df_error), over the calibrated
    tasks' trials."""
    restricted = Targets(
        targets.cells,
        tuple(PooledTest(tuple(x for x in t.tasks if x in names), t.f, t.df_error) for t in targets.pooled),
        targets.source,
    )
    rows = compare(restricted, data, EpisodeConfig().sample_rate)
    for r in rows:
        if "df" in r:
            ref = r["reference"] / (r["reference"] + r["df_reference"])
            f, df = r["simulated"], r["df"]
            sim = f / (f + df) if math.isfinite(f) and math.isfinite(df) else math.nan
            measure = r["statistic"].partition("(")[2].rstrip(")")
            r.update(statistic=f"partial η² strategy ({measure})", reference=ref, simulated=sim,
                     ratio=sim / ref if ref else math.nan, effect_size=True)  # fmt: skip
            del r["df"], r["df_reference"]
    return rows


def write_population(
    result: CalibrationResult, out: str | Path, *, command: str, accept_misses: bool = False
) -> Path:
    """Writes the calibrated population to `out` (a new file: an existing one is a FileExistsError),
    recording the command, seed, phri version, date, targets, the fit and the values the calibration
    started from where they differ (``start``: :meth:`Population.calibration_start` rebuilds the
    starting population, so the command can be rerun without the file it named); a result that
    misses its targets is a CalibrationError naming them, unless `accept_misses`."""
    from phri import __version__

    if not result.reached and not accept_misses:
        raise CalibrationError(f"{result.miss_message()}; nothing written to {out}")
    s = result.settings
    about = {
        "description": (
            f"calibrated with phri calibrate to {result.targets.source} "
            f"(tasks {', '.join(result.targets.tasks)}): "
            f"{s.participants} participants x {s.attempts} attempt(s) per candidate, {result.evaluations} "
            f"candidates, free {', '.join(s.free)}"
            + ("" if result.reached else f"; MISSES: {result.miss_message()}")
        ),
        "command": command,
        "seed": s.seed,
        "phri_version": __version__,
        "date": time.strftime("%Y-%m-%d", time.gmtime()),
        "targets": result.targets.source,
        "fit": result.table(),
        "start": start_record(result.initial or result.start.population, result.population),
    }
    population = Population(result.population.distributions, str(out), tuple(about.items()))
    text = (
        "# A population of simulated participants for phri (see docs/participant.md).\n"
        + population.to_toml()
    )
    return write_atomic(Path(out), text.encode("utf-8"), overwrite=False)
