"""The two-feature task: the study's table task with the cup's tilt (the coffee task's feature) also
learned, or with --base coffee the cup task with the table's height also learned. Does the learning
robot end closer to the desired behaviour than the impedance robot on both features? The
measurements of docs/participant.md ("Two features at once") come from here.

The default population's first --people people (``draw(0, p)``, p = 1, 2, ...) × episode seeds
1..--seeds, each once with impedance and once learning, the way ``phri study`` runs them. Each
episode is scored as the study scores cost: |Φ_k(executed) − Φ_k(desired)| per feature, the
executed path read at the plan's waypoint times. A pair in which either episode ended in a safety
stop is left out and counted. Printed: the initial plan's errors (what the robot does with nobody
touching it), the pairs kept, in how many learning ends closer on the height, on the tilt and on
both, the mean errors, in how many episodes of each strategy every feature ends closer than the
initial plan's, and in how many learning episodes the tilt's weight ended below 0.05.

--decompose adds where the tilt's weight comes from. At each interaction sample of the learning
episodes the learner deformed the plan it followed by the joint torques it measured, U_H (paper eq.
7, phri.Deformation), and moved the tilt's cost weight by −step × the tilt's change ΔΦ. Those
torques are split into the push's force and its torque at the hand, the least-squares wrench ŵ with
Jᵀŵ ≈ U_H (J at the arm's configuration then; the rest, the redundant joint's share, is left
over), and each part deforms the plan last adopted (the one the learner tracks, but while it
blends into it). Summed over samples: the tilt's change to first order (Σ_i ∇Φ(ξ_i)·Δξ_i, which
adds up over the parts), and ΔΦ as the learner computed it (its log's ``interaction_delta_phi``).
Positive sums pull the tilt's weight down; they are not its net change, since the weight stops at
its bounds.

--one-at-a-time: people who correct the most visible error first and only it, until it looks fixed,
then the next (EpisodeConfig.one_at_a_time; HRI 2018); pair it with --rule max.
--precise: people who push exactly where they mean to (off_axis = 0) without tremor (noise = 0).
--deformation-gain MU: the learner's μ (EpisodeConfig.deformation_gain), with the learned features'
steps scaled by phri.Deformation().mu / MU so that the update's first-order step is unchanged.

Usage: python benches/two_features.py [--base table] [--knots 4] [--rule all] [--one-at-a-time]
       [--people 8] [--seeds 3]
       [--precise] [--deformation-gain MU] [--decompose] [--tilt-only]
       (one to four minutes per 48 episodes)
"""

from __future__ import annotations

import argparse
import dataclasses

import numpy as np

import phri
from phri.config import Task
from phri.episode_log import nearest_rows
from phri.sim import EpisodeConfig, World
from phri.sim.episode import Planner, simulate_episode
from phri.sim.participant import default_population
from phri.sim.world import HAND

#: A learning episode's tilt weight below this counts as not learned.
UNLEARNED = 0.05
#: Tilt weights of the plans whose tilt error is printed (the other weights the true ones).
PLAN_TILT_WEIGHTS = (0.0, 0.4)


def two_feature_task(
    knots: int, step_scale: float = 1.0, *, tilt_only: bool = False, base: str = "table"
) -> Task:
    """The `base` task ("table" or "coffee") with the other one's learned feature added (true weight
    1, learned from 0; the table's height or the cup's tilt), or with `tilt_only` the coffee task
    itself, planned by `knots` knots (0: every waypoint); learned features' steps × `step_scale`."""
    tasks = {name: phri.load_task(name) for name in ("table", "coffee")}
    if tilt_only:
        task, features = tasks["coffee"], tasks["coffee"].features
    else:
        task, other = tasks[base], tasks["coffee" if base == "table" else "table"]
        features = (*task.features, other.features[other.feature_names.index(other.task_feature)])
    features = tuple(dataclasses.replace(f, step=f.step * step_scale) if f.learned else f for f in features)
    name = task.name if tilt_only else "_".join(f.name for f in features if f.learned)
    return dataclasses.replace(task, name=name, features=features, knots=knots)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--knots", type=int, default=4, help="plan by this many knots (0: every waypoint)")
    parser.add_argument("--rule", default="all", choices=("all", "max", "confidence"))
    parser.add_argument(
        "--one-at-a-time",
        action="store_true",
        help="people correct the most visible feature first",
    )
    parser.add_argument("--people", type=int, default=8)
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--precise", action="store_true", help="off_axis = 0 and noise = 0")
    parser.add_argument("--deformation-gain", type=float, default=None, metavar="MU")
    parser.add_argument("--decompose", action="store_true")
    parser.add_argument("--tilt-only", action="store_true", help="the coffee task: the tilt learned alone")
    parser.add_argument(
        "--base",
        default="table",
        choices=("table", "coffee"),
        help="the task the other's feature is added to (its start, goal and scene)",
    )
    args = parser.parse_args()
    if args.tilt_only and args.base != "table":
        parser.error("--tilt-only is the coffee task itself: it takes no --base")

    default_mu = phri.Deformation().mu
    mu = default_mu if args.deformation_gain is None else args.deformation_gain
    task = two_feature_task(args.knots, default_mu / mu, tilt_only=args.tilt_only, base=args.base)
    #: The features scored, by their names here; the tilt is the coffee task's feature.
    scored = {"tilt": task.feature_names.index("coffee")}
    if not args.tilt_only:
        scored = {"height": task.feature_names.index("table"), **scored}
    tilt_k = scored["tilt"]
    deformation = phri.Deformation(mu=mu)
    kept, stopped, reasons, unlearned, learned_episodes = [], [], [], 0, 0
    decomposition = np.zeros(4)  # first order: force, torque, U_H; the learner's ΔΦ
    with World() as world:
        planner = Planner(task, world)
        features, model = planner.features, world.model
        desired = features.phi(planner.desired)
        # What the robot does with nobody touching it: its plan for the initial weights.
        untouched_plan = planner.optimizer.solve(task.vector("initial"), task.start, task.goal)[0]
        untouched = np.abs(features.phi(untouched_plan) - desired)[list(scored.values())]
        print(
            "the initial plan (nobody touching): "
            + ", ".join(f"|Δ {name}| {untouched[j]:.2f}" for j, name in enumerate(scored))
        )
        if not args.tilt_only:  # what learning the height without the tilt does to the plan
            for tilt_weight in PLAN_TILT_WEIGHTS:
                weights = task.vector("true")
                weights[tilt_k] = tilt_weight
                plan = planner.optimizer.solve(weights, task.start, task.goal)[0]
                change = abs(features.phi(plan)[tilt_k] - desired[tilt_k])
                print(f"plan for the true weights but a tilt weight of {tilt_weight}: |Δ tilt| {change:.2f}")
        for p in range(1, args.people + 1):
            person = default_population().draw(0, p)
            if args.precise:
                person = dataclasses.replace(person, off_axis=0.0, noise=0.0)
            for seed in range(1, args.seeds + 1):
                off, any_stop = {}, False
                for strategy in ("impedance", "learning"):
                    config = EpisodeConfig(
                        strategy=strategy,
                        rule=args.rule,
                        deformation_gain=args.deformation_gain,
                        one_at_a_time=args.one_at_a_time,
                    )
                    result, error = simulate_episode(task, world, person, config, seed=seed, planner=planner)
                    if error is not None:
                        any_stop = True
                        reasons.append(f"person {p}, seed {seed}, {strategy}: {str(error)[:100]}")
                    off[strategy] = np.abs(result.phi - desired)[list(scored.values())]
                    if strategy == "learning" and error is None:
                        learned_episodes += 1
                        unlearned += result.final_weights[tilt_k] < UNLEARNED
                        if args.decompose:
                            decomposition += _decompose(
                                task, result.log_arrays, features, model, deformation, tilt_k
                            )
                if any_stop:
                    stopped.append((p, seed))
                else:
                    kept.append((off["impedance"], off["learning"]))
    impedance = np.array([i for i, _ in kept])
    learning = np.array([after for _, after in kept])
    closer = learning < impedance
    print(
        f"{task.name} ({' + '.join(scored)} learned), knots={args.knots}, rule={args.rule}, μ={mu:g}"
        f"{', one feature at a time' if args.one_at_a_time else ''}"
        f"{', precise people' if args.precise else ''}: {args.people} people × {args.seeds} seeds"
    )
    print(f"pairs kept {len(kept)}, ended in a safety stop {len(stopped)}: {stopped}")
    for reason in reasons:
        print(f"  {reason}")
    both = f", on every one in {np.all(closer, axis=1).sum()}" if len(scored) > 1 else ""
    closer_on = ", ".join(f"on the {name} in {closer[:, j].sum()}" for j, name in enumerate(scored))
    print(f"learning closer {closer_on}{both}, of {len(kept)}")
    errors = ", ".join(
        f"{name} {impedance[:, j].mean():.2f} -> {learning[:, j].mean():.2f}" for j, name in enumerate(scored)
    )
    print(f"mean error, impedance -> learning: {errors}")
    print(
        "closer than the initial plan on every feature: impedance in "
        f"{np.all(impedance < untouched, axis=1).sum()}, learning in "
        f"{np.all(learning < untouched, axis=1).sum()}, of {len(kept)}"
    )
    print(f"tilt weight below {UNLEARNED} at the end of {unlearned} of {learned_episodes} learning episodes")
    if args.decompose:
        force, torque, whole, learner = decomposition
        print(
            "tilt change from the pushes' deformations (positive: pulls the tilt's weight down): to first "
            f"order, the force's {force:.2f}, the torque's {torque:.2f}, all measured torques' {whole:.2f};"
            f" the learner's ΔΦ {learner:.2f}"
        )


def _decompose(task, log, features, model, deformation, k) -> np.ndarray:
    """Σ over the episode's interaction samples of feature `k`'s first-order change from deforming
    the plan by the measured torques' force part, their torque part and the torques themselves, and
    the learner's own ΔΦ_k: [force, torque, all, learner's]."""
    out = np.zeros(4)
    n = task.waypoints
    spacing = task.duration / (n - 1)
    samples = zip(log["interaction_t"], log["interaction_u_h"], log["interaction_delta_phi"], strict=True)
    for t, u_h, delta_phi in samples:
        if np.isnan(delta_phi[k]):  # nothing deformed (the window ran past the goal)
            continue
        plan = log["plans"][max(int(np.searchsorted(log["plan_t"], t, side="right")) - 1, 0)]
        index = min(int(t / spacing + 1e-9), n - 1)  # the learner's waypoint: the one at or before t
        q = log["q"][nearest_rows(log["t"], np.array([t]))[0]]
        jacobian = model.jacobian(HAND, q)
        wrench = np.linalg.solve(jacobian @ jacobian.T, jacobian @ u_h)
        gradient = features.phi_gradient(plan)[1][k]
        parts = (jacobian[:3].T @ wrench[:3], jacobian[3:].T @ wrench[3:], u_h)
        for row, torques in enumerate(parts):
            out[row] += np.einsum("ij,ij->", gradient, deformation.deform(plan, index, torques) - plan)
        out[3] += delta_phi[k]
    return out


if __name__ == "__main__":
    main()
