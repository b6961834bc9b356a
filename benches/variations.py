"""Does the simulated person see what is wrong off the paper's exact scenes? Random variations of the
study's tasks (``phri.tasks.vary``: objects moved on the table, the table raised or lowered, start
and goal turned, optionally a second learned feature), each run as a small study: the default
population's first --people people (``draw(seed, p)``), once with impedance and once learning, the
way ``phri study`` runs an attempt. docs/participant.md ("Scenes the person was checked on")
reports a run.

A variation is *wrong* when the robot left alone would do noticeably worse than the desired
behaviour: the initial plan's task cost (the unweighted task feature, as the study scores it)
exceeds the desired plan's by more than --wrong (20 %). Checked:

- pushes: in wrong variations, the share of impedance episodes in which the person pushed at all
  (at least --push-share, 80 %);
- learning helps: of the variations in which anyone pushed, the share in which the learning robot
  needed less effort and less interaction time than the impedance robot, on average over the
  people (at least --better-share, 90 %);
- with --second (two learned features), also in how many learning ends closer to the desired
  behaviour's task cost (|cost − desired cost|, averaged over the people).

Episodes that end in a safety stop are counted, and each is printed with its cause (the safety
layer doing its job; they are kept in the averages, as the study keeps them). An episode that ends
in any other error fails the bench.

Usage: python benches/variations.py [--seed S] [--variations 30] [--people 6] [--tasks coffee,...]
       [--second] [--rule all] [--one-at-a-time] [--workers 2] [--verbose]
       (about 10 minutes for 30 variations of each task with 6 people on two cores)
Exit status 1 when a check fails.
"""

from __future__ import annotations

import argparse
import dataclasses
import secrets
import sys
import time
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor

import numpy as np

import phri
from phri.sim import EpisodeConfig, World
from phri.sim.episode import Planner, simulate_episode
from phri.sim.participant import default_population
from phri.study.protocol import episode_seed
from phri.tasks import vary

TASKS = ("coffee", "table", "laptop", "human")
STRATEGIES = ("impedance", "learning")
#: A variation is wrong when the initial plan's task cost exceeds the desired one's by this fraction.
WRONG = 0.2
#: Of the impedance episodes of wrong variations, at least this share has a push.
PUSH_SHARE = 0.8
#: Of the variations with a push, at least this share has learning need less effort and time.
BETTER_SHARE = 0.9


@dataclasses.dataclass(frozen=True)
class Outcome:
    """One variation's small study."""

    task: str
    variation: int
    #: What `vary` changed (the varied task's title).
    changed: str
    initial_cost: float
    desired_cost: float
    #: Per strategy, per person: effort [N·m], interaction time [s], task cost, stopped.
    effort: dict[str, list[float]]
    interaction_time: dict[str, list[float]]
    cost: dict[str, list[float]]
    #: The episodes the safety layer stopped: person, strategy and why.
    stopped: list[str]
    #: The episodes that ended in an error other than a safety stop (a bug): person, strategy, error.
    failed: list[str]

    @property
    def stops(self) -> int:
        return len(self.stopped)

    @property
    def wrong(self) -> bool:
        return self.initial_cost > (1.0 + WRONG) * self.desired_cost

    def pushed(self, strategy: str) -> list[bool]:
        return [t > 0.0 for t in self.interaction_time[strategy]]

    @property
    def anyone_pushed(self) -> bool:
        return any(self.pushed("impedance")) or any(self.pushed("learning"))

    @property
    def learning_better(self) -> bool:
        """Less effort and less interaction time on average over the people."""
        mean = {k: {s: float(np.mean(v[s])) for s in STRATEGIES} for k, v in (
            ("effort", self.effort), ("time", self.interaction_time))}  # fmt: skip
        return all(m["learning"] < m["impedance"] for m in mean.values())

    @property
    def learning_closer(self) -> bool:
        """The learning robot's task cost ends closer to the desired one on average."""
        off = {s: float(np.mean(np.abs(np.asarray(self.cost[s]) - self.desired_cost))) for s in STRATEGIES}
        return off["learning"] < off["impedance"]


def run_variation(
    seed: int,
    task_name: str,
    variation: int,
    people: int,
    second: bool,
    rule: str = "all",
    one_at_a_time: bool = False,
) -> Outcome:
    """Draws variation `variation` of `task_name` from `seed` and runs `people` people on it, the
    learner with update `rule` and the people correcting `one_at_a_time` (EpisodeConfig's)."""
    rng = np.random.default_rng([seed, TASKS.index(task_name) if task_name in TASKS else 99, variation])
    task = vary(phri.load_task(task_name), rng, second=second)
    label = f"{task_name}~{variation}"
    population = default_population()
    effort: dict[str, list[float]] = {s: [] for s in STRATEGIES}
    interaction: dict[str, list[float]] = {s: [] for s in STRATEGIES}
    cost: dict[str, list[float]] = {s: [] for s in STRATEGIES}
    stopped: list[str] = []
    failed: list[str] = []
    with World() as world:
        planner = Planner(task, world)
        initial = planner.optimizer.solve(task.vector("initial"), task.start, task.goal)[0]
        initial_cost = float(planner.features.phi(initial)[task.task_index])
        for p in range(1, people + 1):
            person = population.draw(seed, p)
            for strategy in STRATEGIES:
                result, error = simulate_episode(
                    task,
                    world,
                    person,
                    EpisodeConfig(strategy=strategy, rule=rule, one_at_a_time=one_at_a_time),
                    seed=episode_seed(seed, p, strategy, label, 1),
                    planner=planner,
                )
                if result.stop is not None:
                    stopped.append(f"person {p}, {strategy}: {result.stop.message}")
                elif error is not None:
                    failed.append(f"person {p}, {strategy}: {type(error).__name__}: {error}")
                effort[strategy].append(result.effort)
                interaction[strategy].append(result.interaction_time)
                cost[strategy].append(result.cost)
    return Outcome(
        task_name,
        variation,
        task.title,
        initial_cost,
        planner.desired_cost,
        effort,
        interaction,
        cost,
        stopped,
        failed,
    )


def run(
    seed: int,
    tasks: Sequence[str],
    variations: int,
    people: int,
    *,
    second: bool = False,
    rule: str = "all",
    one_at_a_time: bool = False,
    workers: int = 1,
) -> list[Outcome]:
    """Every variation's outcome, in task then variation order."""
    jobs = [(seed, t, v, people, second, rule, one_at_a_time) for t in tasks for v in range(variations)]
    if workers <= 1:
        return [run_variation(*job) for job in jobs]
    with ProcessPoolExecutor(workers) as pool:
        return list(pool.map(run_variation, *zip(*jobs, strict=True)))


@dataclasses.dataclass(frozen=True)
class Checks:
    """The bench's checks over a run's outcomes."""

    #: Impedance episodes in wrong variations, and how many of them had a push.
    wrong_episodes: int
    wrong_pushed: int
    #: Variations with a push, and in how many learning needed less effort and time.
    pushed_variations: int
    learning_better: int
    #: With two learned features: in how many of the variations with a push learning ended closer.
    learning_closer: int
    stops: int
    #: Episodes that ended in an error other than a safety stop.
    failures: int

    @property
    def push_share(self) -> float:
        return self.wrong_pushed / self.wrong_episodes if self.wrong_episodes else 1.0

    @property
    def better_share(self) -> float:
        return self.learning_better / self.pushed_variations if self.pushed_variations else 1.0

    @property
    def closer_share(self) -> float:
        return self.learning_closer / self.pushed_variations if self.pushed_variations else 1.0


def check(outcomes: Sequence[Outcome]) -> Checks:
    wrong = [o for o in outcomes if o.wrong]
    pushed = [o for o in outcomes if o.anyone_pushed]
    return Checks(
        wrong_episodes=sum(len(o.pushed("impedance")) for o in wrong),
        wrong_pushed=sum(sum(o.pushed("impedance")) for o in wrong),
        pushed_variations=len(pushed),
        learning_better=sum(o.learning_better for o in pushed),
        learning_closer=sum(o.learning_closer for o in pushed),
        stops=sum(o.stops for o in outcomes),
        failures=sum(len(o.failed) for o in outcomes),
    )


def report(outcomes: Sequence[Outcome], tasks: Sequence[str]) -> str:
    lines = [
        f"{'task':8} {'variations':>10} {'wrong':>6} {'imp. pushed':>12} {'learning better':>16} "
        f"{'closer':>7} {'effort L/I':>11} {'time L/I':>9} {'stops':>6}"
    ]
    for name in [*tasks, "all"]:
        mine = [o for o in outcomes if name in ("all", o.task)]
        c = check(mine)
        ratio = {
            k: np.mean([np.mean(getattr(o, k)["learning"]) for o in mine if o.anyone_pushed])
            / max(np.mean([np.mean(getattr(o, k)["impedance"]) for o in mine if o.anyone_pushed]), 1e-12)
            if any(o.anyone_pushed for o in mine)
            else float("nan")
            for k in ("effort", "interaction_time")
        }
        lines.append(
            f"{name:8} {len(mine):>10} {sum(o.wrong for o in mine):>6} "
            f"{f'{c.wrong_pushed}/{c.wrong_episodes}':>12} "
            f"{f'{c.learning_better}/{c.pushed_variations}':>16} "
            f"{f'{c.learning_closer}/{c.pushed_variations}':>7} {ratio['effort']:>11.2f} "
            f"{ratio['interaction_time']:>9.2f} {c.stops:>6}"
        )
    return "\n".join(lines)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seed", type=int, default=None, help="the seed (fresh if absent)")
    parser.add_argument("--variations", type=int, default=30, help="variations of each task")
    parser.add_argument("--people", type=int, default=6, help="people per variation")
    parser.add_argument("--tasks", default=",".join(TASKS), help="comma-separated task names")
    parser.add_argument("--second", action="store_true", help="a second learned feature in every variation")
    parser.add_argument("--rule", default="all", choices=("all", "max", "confidence"), help="the update rule")
    parser.add_argument(
        "--one-at-a-time",
        action="store_true",
        help="people correct the most visible feature first",
    )
    parser.add_argument("--workers", type=int, default=2, help="processes")
    parser.add_argument("--verbose", action="store_true", help="a line per variation")
    args = parser.parse_args()
    seed = secrets.randbits(32) if args.seed is None else args.seed
    tasks = [t for t in args.tasks.split(",") if t]
    print(
        f"seed {seed}: {args.variations} variations of {', '.join(tasks)}"
        f"{' with a second learned feature' if args.second else ''}, {args.people} people each, "
        f"rule {args.rule}{', one feature at a time' if args.one_at_a_time else ''} "
        f"(rerun with --seed {seed})",
        flush=True,
    )
    begun = time.perf_counter()
    outcomes = run(
        seed,
        tasks,
        args.variations,
        args.people,
        second=args.second,
        rule=args.rule,
        one_at_a_time=args.one_at_a_time,
        workers=args.workers,
    )
    if args.verbose:
        for o in outcomes:
            print(
                f"{o.task}~{o.variation}: cost {o.initial_cost:.2f} (desired {o.desired_cost:.2f}), "
                f"pushed {sum(o.pushed('impedance'))}/{len(o.pushed('impedance'))}, "
                f"effort L/I {np.mean(o.effort['learning']):.0f}/{np.mean(o.effort['impedance']):.0f}, "
                f"time L/I {np.mean(o.interaction_time['learning']):.2f}/"
                f"{np.mean(o.interaction_time['impedance']):.2f} s; {o.changed}"
            )
    for o in outcomes:
        for why in o.stopped:
            print(f"stopped: {o.task}~{o.variation}, {why}")
        for why in o.failed:
            print(f"FAILED: {o.task}~{o.variation}, {why}")
    print(report(outcomes, tasks))
    c = check(outcomes)
    ok = c.push_share >= PUSH_SHARE and c.better_share >= BETTER_SHARE and c.failures == 0
    if args.second:
        ok = ok and c.closer_share >= BETTER_SHARE
    print(
        f"pushed in {c.push_share:.0%} of impedance episodes of wrong variations (>= {PUSH_SHARE:.0%}); "
        f"learning needed less effort and time in {c.better_share:.0%} of variations with a push "
        f"(>= {BETTER_SHARE:.0%}); learning ended closer in {c.closer_share:.0%}; {c.stops} stops; "
        f"{time.perf_counter() - begun:.0f} s: {'ok' if ok else 'FAILED'}"
    )
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
