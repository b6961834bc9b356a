"""The learner's belief over the weights and its rationality estimate β̂ (phri_core's belief
module), checked against things computed without them: a numerical posterior on a grid, whose
normaliser is a Monte Carlo integral over pushes through the real deformation and features, and the
plain projection of a push onto the features' sensitivity."""

import dataclasses

import numpy as np
import pytest

import phri
from phri import Deformation, InteractionDetector, Learner, WeightUpdate, load_task
from phri.exceptions import InvalidParameterError, NonFiniteError, ShapeError
from phri.sim.episode import Planner
from phri.tasks import vary

#: Pushes of the small problem: sample times [s] and joint torques [N·m] (every joint above the
#: detector's thresholds, so u_H is the push itself).
PUSHES = tuple(
    (
        1.0 + 1.5 * i,
        np.array([1.0, -6.0, 2.0, -4.0, 1.5, -1.0, 1.0]) * np.random.default_rng(i).uniform(0.5, 1.5, 7),
    )
    for i in range(8)
)
#: λ [1/(N·m)²]: pushes spread by about 1.6 N·m per joint under the model. The belief linearises the
#: features along the push; with a spread of 3 N·m (λ = 0.05) the tilt's curvature along it puts
#: the numerical posterior's variance 15 % above the belief's (docs/concepts.md).
EFFORT = 0.2


def learner_for(task, planner, *, rule="all", deformation=None, **options) -> Learner:
    """A learner of `task` whose detector sees every push whole (thresholds 0.5 N·m)."""
    update = WeightUpdate(
        task.vector("step"),
        task.vector("lower"),
        task.vector("upper"),
        learned=[f.learned for f in task.features],
        rule=rule,
    )
    return Learner(
        planner.features, deformation or Deformation(), update, InteractionDetector([0.5] * 7),
        planner.optimizer, task.vector("initial"), task.start, task.goal, duration=task.duration, **options,
    )  # fmt: skip


@pytest.fixture(scope="module")
def two_weights():
    """The table task with the cup's tilt learned too: a learner that records the plan it tracked
    at each push (it switches plans at once, so the plan is what it tracks)."""
    task = vary(
        load_task("table"), np.random.default_rng(0), move=0.0, table_height=0.0, pose=0.0, second=True
    )
    robot = phri.Robot.jaco2()
    planner = Planner(task, robot)
    deformation = Deformation()
    learner = learner_for(task, planner, deformation=deformation, transition_speed=0.0, effort=EFFORT)
    tracked = []
    for t, tau in PUSHES:
        learner.observe(t - 0.1, np.zeros(7))
        tracked.append(learner.plan.copy())
        learner.observe(t, tau)
    return task, planner, deformation, learner, tracked


def test_covariance_matches_a_numerical_posterior(two_weights):
    task, planner, deformation, learner, tracked = two_weights
    learned = np.array([f.learned for f in task.features])
    assert learned.sum() == 2
    _, covariance = learner.belief()
    sigma = covariance[np.ix_(learned, learned)]
    # The posterior over the reward weights θ = −w of the two learned features, on a grid: the
    # prior of eq. 11 (variance = step) times each push's likelihood of eq. 8, normalised by
    # Z(θ) = ∫ exp(θᵀΔΦ(u) − λ‖u‖²) du through the real deformation and features, by Monte Carlo
    # over u ~ N(0, I/(2λ)). The observed ΔΦ's only shift the mean; the covariance is Z's doing.
    rng = np.random.default_rng(1)
    samples = rng.normal(0.0, 1.0 / np.sqrt(2 * EFFORT), (6000, 7))
    fixed = -task.vector("initial")[~learned]  # the known weights, as rewards
    log_z = []
    half = 5.0 * np.sqrt(np.diag(sigma))
    grid = [np.linspace(-h, h, 61) for h in half]  # about θ = 0, the prior's mean (initial 0)
    theta = np.stack(np.meshgrid(*grid, indexing="ij"), -1).reshape(-1, 2)
    features = planner.features
    for (t, _), xi in zip(PUSHES, tracked, strict=True):
        index = int(np.floor(t / (task.duration / (task.waypoints - 1))))
        phi_r = features.phi(xi)
        delta = np.array([features.phi(deformation.deform(xi, index, u)) - phi_r for u in samples])
        known = delta[:, ~learned] @ fixed
        exponent = theta @ delta[:, learned].T + known  # (grid, samples)
        top = exponent.max(axis=1, keepdims=True)
        log_z.append(np.log(np.exp(exponent - top).mean(axis=1)) + top[:, 0])
    prior = task.vector("step")[learned]
    log_post = -0.5 * (theta**2 / prior).sum(axis=1) - np.sum(log_z, axis=0)
    p = np.exp(log_post - log_post.max())
    p /= p.sum()
    mean = p @ theta
    numeric = ((theta - mean) * p[:, None]).T @ (theta - mean)
    assert np.all(np.abs(np.diag(sigma) / np.diag(numeric) - 1) < 0.10), (sigma, numeric)
    corr = lambda c: c[0, 1] / np.sqrt(c[0, 0] * c[1, 1])  # noqa: E731
    assert abs(corr(sigma) - corr(numeric)) < 0.10, (sigma, numeric)
    # The pushes were informative: the tilt's posterior is well inside its prior.
    assert np.diag(sigma)[1] < 0.8 * prior[1] and np.diag(sigma)[0] < prior[0]


def test_covariance_shrinks_along_corrected_features_only():
    """The table task with a keep-out around the person learned too: its plans keep far from the
    person, where the keep-out has no gradient, so no push can change it. The belief narrows on
    the table's weight and keeps its prior on the person's."""
    task = load_task("table")
    robot = phri.Robot.jaco2()
    human = load_task("human")
    spec = human.features[human.feature_names.index("human")]
    task = dataclasses.replace(task, features=(*task.features, dataclasses.replace(spec, initial=0.0)))
    planner = Planner(task, robot)
    learner = learner_for(task, planner)
    _, prior = learner.belief()
    for t, tau in PUSHES:
        learner.observe(t, tau)
    _, after = learner.belief()
    table, person = task.feature_names.index("table"), task.feature_names.index("human")
    assert after[table, table] < 0.75 * prior[table, table]
    assert after[person, person] == pytest.approx(prior[person, person], rel=1e-6)
    assert np.all(after[0] == 0) and np.all(after[:, 0] == 0), "efficiency is not learned: no variance"
    history = learner.history()
    assert history.covariance.shape == (len(history), 3, 3)
    np.testing.assert_array_equal(history.covariance[-1], after)
    learner.reset()
    np.testing.assert_array_equal(learner.belief()[1], prior)


def test_rationality_is_the_projection_of_the_push():
    rng = np.random.default_rng(2)
    s = rng.normal(size=(3, 7))
    learned = [False, True, True]
    u = rng.normal(size=7)
    beta, explained, rank = phri.rationality(s, learned, u)
    q, _ = np.linalg.qr(s[1:].T)
    projected = q @ (q.T @ u)
    want = projected @ projected / (u @ u)
    assert rank == 2 and explained == pytest.approx(want, rel=1e-12)
    assert beta == pytest.approx((want / 2) / ((1 - want) / 5), rel=1e-10)
    # A push along a learned row is explained; across all of them, not at all.
    assert phri.rationality(s, learned, s[1])[0] == phri.BETA_MAX
    across = u - projected
    assert phri.rationality(s, learned, across)[0] == pytest.approx(0.0, abs=1e-12)
    with pytest.raises(NonFiniteError, match="sensitivity"):
        phri.rationality(np.full((3, 7), np.nan), learned, u)
    with pytest.raises(ShapeError, match="sensitivity"):
        phri.rationality(s[:, :6], learned, u)


def test_beta_rule_scales_the_step_by_rationality(two_weights):
    """The "beta" rule steps the weights by min(1, β̂ / BETA_FULL) of the paper's step."""
    task, planner, _, _, _ = two_weights
    learned = [f.learned for f in task.features]

    def first_push(rule: str):  # -> the learner's history
        learner = learner_for(task, planner, rule=rule)
        learner.observe(1.0, np.array([0.0, 0.0, 0.0, 0.0, 3.0, 0.0, 0.0]))  # a wrist push, partly explained
        return learner.history()

    beta, paper = first_push("beta"), first_push("all")
    assert beta.beta[0] == paper.beta[0] and beta.explained[0] == paper.explained[0]
    scale = min(1.0, beta.beta[0] / phri.BETA_FULL)
    assert 0 < scale < 1, "the push is partly explained: the step is scaled"
    step, initial = task.vector("step"), task.vector("initial")
    want = np.clip(
        initial - scale * step * paper.delta_phi[0] * learned, task.vector("lower"), task.vector("upper")
    )
    np.testing.assert_allclose(beta.weights[0], want, rtol=1e-12, atol=1e-15)
    assert np.any(beta.weights[0] != paper.weights[0])


def test_risk_aware_planning_weights(two_weights):
    task, planner, _, _, _ = two_weights
    learned = np.array([f.learned for f in task.features])
    risk = np.where(learned, 0.1, 0.0)
    learner = learner_for(task, planner, risk=risk)
    mean, covariance = learner.belief()
    want = np.clip(mean + risk * np.sqrt(np.diag(covariance)), task.vector("lower"), task.vector("upper"))
    np.testing.assert_array_equal(learner.plan_weights, want)
    assert np.all(learner.plan_weights[learned] > mean[learned])
    with pytest.raises(NonFiniteError, match="risk"):
        learner_for(task, planner, risk=[np.nan] * len(learned))
    with pytest.raises(ShapeError, match="risk"):
        learner_for(task, planner, risk=[0.1])
    with pytest.raises(InvalidParameterError, match="effort"):
        learner_for(task, planner, effort=0.0)


def test_an_episode_plans_with_risk_and_logs_the_belief():
    from phri.sim.episode import EpisodeConfig, make_learner
    from phri.study import StudyConfig

    task = load_task("table")
    planner = Planner(task, phri.Robot.jaco2())
    config = EpisodeConfig(risk=0.5)
    learner = make_learner(task, planner, config, [8.0, 8, 8, 2, 1, 1, 1], replan_latency=0.0)
    mean, covariance = learner.belief()
    table = task.feature_names.index("table")
    assert learner.plan_weights[table] == pytest.approx(mean[table] + 0.5 * np.sqrt(covariance[table, table]))
    assert learner.plan_weights[0] == mean[0], "efficiency is not learned: planned at its weight"
    assert StudyConfig(risk=0.5).episode_config("learning").risk == 0.5
    for bad in (float("nan"), True, "1"):
        with pytest.raises(InvalidParameterError, match="risk"):
            EpisodeConfig(risk=bad)
