"""Tests of the matching curriculum (d2c_jax/curriculum.py)."""

import dataclasses
import inspect

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from d2c_jax.config import ClassifierConfig, CurriculumConfig
from d2c_jax.curricula import classifier as clf
from d2c_jax.curricula import curriculum as cur
from d2c_jax.curricula import goal_switch
from envs.base import GoalEnv


class GoalBox:
    """Just the goal interface of a GoalEnv (no physics): modes, radius, bounds."""

    clip_goal = GoalEnv.clip_goal
    sample_uniform_goals = GoalEnv.sample_uniform_goals

    def __init__(self, modes, low, high, radius=0.5, mask=None):
        self.goal_points = np.asarray(modes, np.float32)
        self.goal_low = np.asarray(low, np.float32)
        self.goal_high = np.asarray(high, np.float32)
        self.goal_dim = self.goal_low.shape[0]
        self.success_radius = radius
        ones = np.ones(self.goal_dim, np.float32)
        self.goal_noise_mask = ones if mask is None else np.asarray(mask, np.float32)


# Two modes of the medium maze, its bounds and radius.
ENV = GoalBox([[16.0, 16.0], [-16.0, -16.0]], [-18.0, -18.0], [18.0, 18.0])


class DistanceNet(nn.Module):
    """An analytic 'classifier': both heads = sigmoid(4 - ||x - g||^2 / scale)."""

    scale: float = 4.0

    @nn.compact
    def __call__(self, x, g):
        logit = 4.0 - jnp.sum((x - g) ** 2, axis=-1, keepdims=True) / self.scale
        return jnp.concatenate([logit, logit], axis=-1)


DIST = DistanceNet()
NO_PARAMS = {}


def _lines(ends, horizon=11):
    """(P, T, 2) straight trajectories from the origin to each end point."""
    frac = np.linspace(0.0, 1.0, horizon)[None, :, None]
    return jnp.asarray(frac * np.asarray(ends, np.float32)[:, None, :], jnp.float32)


# Pool: 1 ends next to mode 0, 3 next to mode 1, 4 and 5 nearer the modes than 0 and 2.
ENDS = [[-5.0, 3.0], [15.9, 16.1], [3.0, -4.0], [-15.8, -16.0], [14.0, 14.5], [-13.0, -14.0]]
POOL = _lines(ENDS)
EPS = 0.5  # curriculum goal noise half-width
CFG = CurriculumConfig(n_slots=4, pool_size=6, cost_stride=4, goal_noise=EPS)
GAMMA = 0.99  # the SAC discount, for the value terms


def filled(pool: jax.Array, count) -> jax.Array:
    """(P,) bool validity of a pool whose first `count` entries hold episodes."""
    return jnp.arange(pool.shape[0]) < count


def _propose(cfg, env, net, params, value_fn=None):
    """Jitted `propose` with the pool and the number of its episodes traced."""
    return jax.jit(
        lambda pool, count, start, key: cur.propose(
            cfg,
            env,
            net,
            params,
            pool,
            filled(pool, count),
            start,
            key,
            value_fn=value_fn,
            gamma=GAMMA,
        )  # fmt: skip
    )


RUN = _propose(CFG, ENV, DIST, NO_PARAMS)  # compiled once, shared by the tests below


# --- examples and slots -----------------------------------------------------------


def test_desired_examples_and_slots():
    env = GoalBox([[0.5, 0.9, 0.02], [-0.3, 0.4, 0.02]], [-0.6, 0.2, 0.0], [0.6, 1.0, 0.3],
                  radius=0.05, mask=[1.0, 1.0, 0.0])  # fmt: skip
    ex = jax.jit(cur.desired_examples, static_argnums=(0, 1))(env, 2000, jax.random.key(0))
    assert ex.shape == (2, 2000, 3)
    np.testing.assert_allclose(ex[1].mean(0), env.goal_points[1], atol=3e-3)
    np.testing.assert_allclose(ex[1, :, :2].std(0), 0.025, rtol=0.1)  # radius / 2
    np.testing.assert_array_equal(ex[..., 2], np.float32(0.02))  # masked z: no noise
    assert np.all(ex[0, :, 1] <= 1.0)  # clipped to the bounds (mode 0 is near y = 1)
    slots = jax.jit(cur.goal_slots, static_argnums=(0, 1))(env, 5, jax.random.key(1))
    nearest = np.linalg.norm(slots[:, None] - env.goal_points[None], axis=-1).argmin(1)
    np.testing.assert_array_equal(nearest, [0, 1, 0, 1, 0])  # mode j mod n_modes


def test_subsample_keeps_every_stride_and_the_final_step():
    traj = jnp.arange(10.0)[None, :, None]
    np.testing.assert_array_equal(cur.subsample(traj, 4)[0, :, 0], [0, 4, 8, 9])
    np.testing.assert_array_equal(cur.subsample(traj[:, :9], 4)[0, :, 0], [0, 4, 8])


# --- Eq. 7 ---------------------------------------------------------------------------


def test_cost_matrix_matches_brute_force():
    ccfg = ClassifierConfig(n_heads=2, hidden_sizes=(16, 16))
    net = clf.make_classifier(ccfg, ENV)
    init = jax.jit(clf.init_classifier, static_argnums=(0, 1, 2))
    params = init(net, clf.make_optimizer(), 2, jax.random.key(0))
    params = jax.tree.map(lambda w: 3.0 * w, params.params)  # sharper, more varied p
    slots = jnp.array([[16.0, 16.0], [-10.0, 5.0], [2.0, -3.0]])
    pool = jax.random.uniform(jax.random.key(1), (4, 7, 2), minval=-18.0, maxval=18.0)
    cost, cand = jax.jit(lambda p: cur.cost_matrix(net, p, slots, pool, 3))(params)
    assert cost.shape == (3, 4) and cand.shape == (3, 4, 2)
    heads = jax.jit(lambda x, g: clf.p_pseudo(net, params, x, g))
    steps = [0, 3, 6]
    for j in range(3):
        y = float(heads(slots[j], slots[j]))
        for k in range(4):
            p = np.asarray(heads(pool[k, steps], slots[j]), np.float64)
            w = -(y * np.log(p) + (1 - y) * np.log(1 - p))  # soft-target BCE
            assert float(cost[j, k]) == pytest.approx(w.min(), rel=1e-4)
            np.testing.assert_array_equal(cand[j, k], pool[k, steps[int(w.argmin())]])


def test_cost_keeps_ranking_where_p_underflows():
    """Far from the slot p_pseudo underflows float32 (logit -300 and below), yet states
    nearer the slot still cost less: the Eq. 7 BCE is taken in log space."""
    sharp = DistanceNet(scale=0.5)
    slots = jnp.array([[16.0, 16.0]])
    far = jnp.array([[[0.0, 0.0], [4.0, 4.0]], [[-8.0, 0.0], [-6.0, 0.0]]])  # (2, 2, 2)
    assert float(clf.p_pseudo(sharp, NO_PARAMS, far[0, 1], slots[0])) == 0.0  # underflow
    cost, cand = cur.cost_matrix(sharp, NO_PARAMS, slots, far, 1)
    np.testing.assert_array_equal(cand[0, 0], [4.0, 4.0])
    # Exact BCE: y softplus(-z) + (1 - y) softplus(z), y = p(g+; g+) = sigmoid(4).
    logit, y = 4.0 - 2 * 12.0**2 / 0.5, 1.0 / (1.0 + np.exp(-4.0))
    expected = y * np.logaddexp(0.0, -logit) + (1 - y) * np.logaddexp(0.0, logit)
    assert float(cost[0, 0]) == pytest.approx(expected, rel=1e-5)
    assert float(cost[0, 0]) < float(cost[0, 1])


def test_value_variant_subtracts_scaled_value():
    slots = jnp.array([[16.0, 16.0], [-16.0, -16.0]])
    base, _ = cur.cost_matrix(DIST, NO_PARAMS, slots, POOL, 4)
    value = lambda g: jnp.full(g.shape[:-1], 50.0)  # noqa: E731  constant V
    shifted, _ = cur.cost_matrix(DIST, NO_PARAMS, slots, POOL, 4, value, value_scale=0.01)
    np.testing.assert_allclose(shifted, base - 0.5, atol=1e-5)  # (1 - 0.99) * 50


class FlatNet(nn.Module):
    """A classifier that says 0.5 everywhere: every candidate is equally novel."""

    @nn.compact
    def __call__(self, x, g):
        return jnp.zeros(x.shape[:-1] + (2,))


def test_goal_value_breaks_ties_between_equally_novel_candidates():
    """With p_pseudo = 0.5 everywhere every edge costs log 2; V(s, g_j) then picks, for
    each slot, the pool state the critic rates nearest its desired example."""
    slots = jnp.array([[16.0, 16.0], [-16.0, -16.0]])
    pool_obs = POOL  # stand-in observations: the states' xy

    def goal_value_fn(obs, goal):  # a critic that knows the straight-line distance
        return 100.0 - jnp.linalg.norm(obs - goal, axis=-1)

    flat, _ = cur.cost_matrix(FlatNet(), NO_PARAMS, slots, POOL, 4)
    np.testing.assert_allclose(flat, np.log(2.0), atol=1e-6)  # a tie everywhere
    cost, cand = cur.cost_matrix(
        FlatNet(), NO_PARAMS, slots, POOL, 4,
        pool_obs=pool_obs, goal_value_fn=goal_value_fn, goal_value_scale=0.01,
    )  # fmt: skip
    np.testing.assert_array_equal(np.asarray(cost).argmin(1), [1, 3])  # the two mode ends
    states = np.asarray(cur.subsample(POOL, 4))  # (P, T', 2) the scored states
    dist = np.linalg.norm(states[None] - np.asarray(slots)[:, None, None], axis=-1)
    want = np.log(2.0) - 0.01 * (100.0 - dist.min(axis=-1))  # each line's nearest state
    np.testing.assert_allclose(cost, want, atol=1e-5)
    np.testing.assert_allclose(cand[0, 1], ENDS[1], atol=1e-6)
    cfg = dataclasses.replace(CFG, n_slots=2, goal_value_weight=1.0)
    goals, _ = jax.jit(
        lambda: cur.propose(
            cfg, ENV, FlatNet(), NO_PARAMS, POOL, filled(POOL, 6), jnp.zeros(2),
            jax.random.key(0), gamma=GAMMA, pool_obs=pool_obs, goal_value_fn=goal_value_fn,
        )
    )()  # fmt: skip
    assert np.linalg.norm(goals - ENV.goal_points, axis=-1).max() < 1.5
    with pytest.raises(ValueError, match="pool_obs"):  # the value term needs the states
        cur.propose(
            cfg,
            ENV,
            FlatNet(),
            NO_PARAMS,
            POOL,
            filled(POOL, 6),
            jnp.zeros(2),
            jax.random.key(0),
            gamma=GAMMA,
            goal_value_fn=goal_value_fn,
        )


# --- matching ------------------------------------------------------------------------


def test_trajectory_ending_at_a_mode_is_matched_to_it():
    goals, m = RUN(POOL, 6, jnp.zeros(2), jax.random.key(0))
    slots_mode = np.arange(4) % 2  # slot j is mode j mod 2
    # Each goal is its candidate (a pool state) + U[-0.5, 0.5] noise; find the trajectory.
    ends = np.asarray(ENDS)
    used = np.abs(np.asarray(goals)[:, None] - ends[None]).max(-1).argmin(1)  # (K,)
    assert np.all(np.abs(np.asarray(goals) - ends[used]).max(-1) <= 0.5)
    assert len(set(used.tolist())) == 4  # no trajectory used twice
    assert set(used.tolist()) == {1, 3, 4, 5}  # the four nearest the modes
    assert slots_mode[list(used).index(1)] == 0  # ends next to mode 0 -> a mode-0 slot
    assert slots_mode[list(used).index(3)] == 1
    assert slots_mode[list(used).index(4)] == 0 and slots_mode[list(used).index(5)] == 1
    assert float(m["curriculum/pool_full"]) == 1.0
    # curriculum/slot_distance = mean ||goal_j - g_j+||; slots are within ~1 of their modes.
    to_mode = np.linalg.norm(np.asarray(goals) - ENV.goal_points[slots_mode], axis=-1).mean()
    assert float(m["curriculum/slot_distance"]) == pytest.approx(to_mode, abs=1.0)
    # The paper's distance matches the two sets optimally: never above the slot pairing.
    assert float(m["curriculum/distance"]) <= float(m["curriculum/slot_distance"]) + 1e-5


def test_goal_noise_is_the_curriculum_config_s():
    """Goal j = its matched candidate (a subsampled pool state) + U[-c, c] noise with
    c = cfg.goal_noise, or the traced `hp.goal_noise` the trainer passes from its
    hyperparameters: c = 0 gives the candidates exactly. The classifier's eps is no
    argument, and the discount has no default of its own (it is SACConfig.gamma)."""
    states = np.asarray(cur.subsample(POOL, CFG.cost_stride)).reshape(-1, 2)
    gaps = {}
    for c in (0.0, 1.5):
        cfg = dataclasses.replace(CFG, goal_noise=c)
        goals, _ = _propose(cfg, ENV, DIST, NO_PARAMS)(POOL, 6, jnp.zeros(2), jax.random.key(0))
        gaps[c] = np.abs(np.asarray(goals)[:, None] - states[None]).max(-1).min(-1)  # (K,)
    np.testing.assert_array_equal(gaps[0.0], 0.0)
    assert np.all(gaps[1.5] <= 1.5 + 1e-5) and gaps[1.5].max() > 0.5
    traced = jax.jit(
        lambda c: cur.propose(
            dataclasses.replace(CFG, goal_noise=1.5), ENV, DIST, NO_PARAMS, POOL,
            filled(POOL, 6), jnp.zeros(2), jax.random.key(0), gamma=GAMMA,
            hp=cur.hyperparams(CFG).replace(goal_noise=c),
        )[0]
    )  # fmt: skip
    np.testing.assert_array_equal(traced(jnp.float32(0.0)), _propose(
        dataclasses.replace(CFG, goal_noise=0.0), ENV, DIST, NO_PARAMS
    )(POOL, 6, jnp.zeros(2), jax.random.key(0))[0])  # fmt: skip
    params = inspect.signature(cur.propose).parameters
    assert "eps" not in params and params["gamma"].default is inspect.Parameter.empty


def test_matched_distance_equals_scipy_optimal_matching():
    from scipy.optimize import linear_sum_assignment

    rng = np.random.default_rng(0)
    for _ in range(5):
        goals, desired = rng.uniform(-18, 18, (2, 20, 2)).astype(np.float32)
        dist = np.linalg.norm(goals[:, None] - desired[None], axis=-1)
        rows, cols = linear_sum_assignment(dist)
        got = float(jax.jit(cur.matched_distance)(goals, desired))
        assert got == pytest.approx(dist[rows, cols].mean(), rel=1e-4)
    # Hand-computed: all goals on mode 0 while half the desired examples are mode 1.
    desired = jnp.asarray([[16.0, 16.0], [16.0, 16.0], [-16.0, -16.0], [-16.0, -16.0]])
    goals = jnp.full((4, 2), 16.0)
    assert float(cur.matched_distance(goals, desired)) == pytest.approx(32 * np.sqrt(2) / 2)


def test_value_variant_trades_cost_against_value():
    # V on the two trajectories that stay near the start (0 and 2), 0 elsewhere.
    def value_fn(v):
        def fn(g):
            near_start = jnp.linalg.norm(g[:, -1], axis=-1) < 6.0  # (P,)
            return jnp.broadcast_to(v * near_start[:, None], g.shape[:-1])

        return fn

    slots = jnp.array([[16.0, 16.0], [-16.0, -16.0]])
    costs = {
        v: np.asarray(cur.cost_matrix(DIST, NO_PARAMS, slots, POOL, 4, value_fn(v), 0.01)[0])
        for v in (100.0, 1e5)
    }
    # V <= 1/(1-gamma) = 100: a bonus of at most 1 cannot beat reaching the mode (w ~ 0.1
    # against more for a trajectory that never gets near it): 1 and 3 stay the cheapest.
    np.testing.assert_array_equal(costs[100.0].argmin(1), [1, 3])
    np.testing.assert_array_equal(costs[1e5][:, [0, 2]] < costs[1e5][:, [1, 3]], True)
    cfg = dataclasses.replace(CFG, variant="value", n_slots=2)
    goals, m = _propose(cfg, ENV, DIST, NO_PARAMS, value_fn(100.0))(
        POOL, 6, jnp.zeros(2), jax.random.key(0)
    )
    assert np.linalg.norm(goals - ENV.goal_points, axis=-1).max() < 1.5
    with pytest.raises(ValueError, match="value_fn"):
        cur.propose(
            cfg, ENV, DIST, NO_PARAMS, POOL, filled(POOL, 6), jnp.zeros(2), jax.random.key(0),
            gamma=GAMMA,
        )  # fmt: skip


def test_warmup_fallback_with_an_empty_pool():
    start = jnp.array([0.05, -0.05])
    empty = jnp.zeros_like(POOL)
    for valid in (0, 5):
        goals, m = RUN(empty, valid, start, jax.random.key(valid))
        assert float(m["curriculum/pool_full"]) == 0.0
        assert np.all(np.linalg.norm(goals - start, axis=-1) < 4 * ENV.success_radius)
    assert not cur.pool_full(jnp.array([True] * 5 + [False]))
    assert cur.pool_full(jnp.ones(6, bool))
    # The fallback distribution: start + N(0, radius^2), clipped.
    warm = cur.warmup_goals(ENV, jnp.array([17.8, 0.0]), 4000, jax.random.key(1))
    assert np.all(warm <= 18.0)
    np.testing.assert_allclose(warm[:, 1].std(), 0.5, rtol=0.1)
    # Vmapped seeds: one with an empty pool, one with a full one, in the same program.
    batched = jax.vmap(RUN, in_axes=(0, 0, None, 0))
    keys = jax.random.split(jax.random.key(2), 2)
    goals, m = batched(jnp.stack([empty, POOL]), jnp.array([0, 6]), start, keys)
    np.testing.assert_array_equal(m["curriculum/pool_full"], [0.0, 1.0])
    assert np.all(np.linalg.norm(goals[0] - start, axis=-1) < 4 * ENV.success_radius)
    assert np.linalg.norm(goals[1] - ENV.goal_points[np.arange(4) % 2], axis=-1).max() < 6.0


def test_no_curriculum_variant_uses_desired_examples():
    cfg = dataclasses.replace(CFG, variant="none")
    goals, m = _propose(cfg, ENV, DIST, NO_PARAMS)(POOL, 0, jnp.zeros(2), jax.random.key(0))
    modes = ENV.goal_points[np.arange(4) % 2]
    assert np.all(np.linalg.norm(goals - modes, axis=-1) < 4 * 0.25)
    assert float(m["curriculum/distance"]) == 0.0


# --- after success (SPEC §6) ---------------------------------------------------------


def test_post_success_goal_moves_towards_the_modes():
    net = DistanceNet(scale=100.0)  # p_pseudo decreases with the distance to the nearest mode
    cfg = CurriculumConfig(post_success_range=2.5)
    choose = jax.jit(
        jax.vmap(lambda ag, key: goal_switch.post_success_goal(cfg, ENV, net, NO_PARAMS, ag, key))
    )
    keys = jax.random.split(jax.random.key(0), 200)
    ag = jnp.broadcast_to(jnp.array([14.0, 14.0]), (200, 2))
    goals = np.asarray(choose(ag, keys))
    assert goals.shape == (200, 2)
    assert np.all(np.abs(goals - 14.0) <= 2.5)  # within the candidate box
    # Best of 16 candidates in [11.5, 16.5]^2: close to (16, 16); a random one is ~2.9 away.
    assert np.linalg.norm(goals - 16.0, axis=-1).mean() < 1.2
    # At the border the candidates are clipped into the goal bounds (mode on the corner).
    env = GoalBox([[18.0, 18.0]], [-18.0, -18.0], [18.0, 18.0])
    corner = jax.jit(
        jax.vmap(
            lambda key: goal_switch.post_success_goal(
                cfg, env, net, NO_PARAMS, jnp.full(2, 17.5), key
            )
        )
    )(keys)
    assert np.all(corner <= 18.0) and np.mean(np.any(corner == 18.0, axis=-1)) > 0.5


def test_propose_on_the_medium_maze(medium_maze):
    env = medium_maze
    ccfg = ClassifierConfig(n_heads=2, hidden_sizes=(16, 16))
    net = clf.make_classifier(ccfg, env)
    params = jax.jit(clf.init_classifier, static_argnums=(0, 1, 2))(
        net, clf.make_optimizer(), env.goal_dim, jax.random.key(0)
    ).params
    cfg = CurriculumConfig(n_slots=4, pool_size=8, goal_noise=EPS)
    pool = jax.random.uniform(jax.random.key(1), (8, 101, 2), minval=-18.0, maxval=18.0)
    goals, m = _propose(cfg, env, net, params)(pool, 8, jnp.zeros(2), jax.random.key(2))
    assert goals.shape == (4, 2) and np.all(np.abs(goals) <= 18.0)
    # Each goal is a (subsampled) pool state plus U[-eps, eps]^2 noise.
    states = np.asarray(cur.subsample(pool, cfg.cost_stride)).reshape(-1, 2)
    gap = np.abs(np.asarray(goals)[:, None] - states[None]).max(-1).min(-1)
    assert np.all(gap <= EPS + 1e-5)
    assert (
        set(m)
        == set(cur.METRIC_KEYS)
        == {
            "curriculum/distance",
            "curriculum/slot_distance",
            "curriculum/matched_cost",
            "curriculum/pool_full",
            "curriculum/auction_converged",
        }
    )
    assert float(m["curriculum/auction_converged"]) == 1.0
    assert np.isfinite(float(m["curriculum/distance"]))


def test_relaxed_threshold_hand_computed():
    scores = jnp.asarray([0.1, 0.35, 0.2])
    # 0.4 is not reached; 0.38, 0.36 neither; 0.34 is (by 0.35).
    assert float(goal_switch.relaxed_threshold(scores, 0.4, 0.02)) == pytest.approx(0.34)
    assert float(
        goal_switch.relaxed_threshold(jnp.asarray([0.5, 0.1]), 0.4, 0.02)
    ) == pytest.approx(0.4)
    assert float(goal_switch.relaxed_threshold(jnp.asarray([0.36]), 0.4, 0.02)) == pytest.approx(
        0.36
    )


class ScoreNet(nn.Module):
    """Both heads = sigmoid(z) with z a fixed function of x alone: p(x) = sigmoid(x_0)."""

    @nn.compact
    def __call__(self, x, g):
        z = x[..., :1] + 0.0 * g[..., :1]
        return jnp.concatenate([z, z], axis=-1)


def test_outpace_rule_samples_qualifying_candidates_by_softmax():
    """With C candidates the rule keeps those with p >= the (relaxed) threshold and samples
    them by softmax(p / T): compare the frequencies with the hand-computed distribution."""
    cfg = CurriculumConfig(
        post_success_rule="outpace", post_success_candidates=10, post_success_range=2.0
    )
    env = GoalBox([[0.0, 0.0]], [-18.0, -18.0], [18.0, 18.0])
    keys = jax.random.split(jax.random.key(0), 4000)
    pick = jax.jit(
        jax.vmap(lambda k: goal_switch.post_success_goal(cfg, env, ScoreNet(), {}, jnp.zeros(2), k))
    )
    goals = np.asarray(pick(keys))
    cands, scores = jax.vmap(
        lambda k: goal_switch.candidate_scores(env, ScoreNet(), {}, jnp.zeros(2), k, 10, 2.0)
    )(keys)
    cands, scores = np.asarray(cands), np.asarray(scores)
    chosen = np.argmin(np.abs(cands - goals[:, None]).sum(-1), axis=1)  # which candidate
    np.testing.assert_allclose(cands[np.arange(4000), chosen], goals, atol=1e-6)
    p = scores[np.arange(4000), chosen]
    # Every pick qualifies: p >= 0.4, or the best of its candidates when none reaches 0.4.
    best = scores.max(axis=1)
    assert np.all((p >= 0.4 - 1e-6) | (best < 0.4))
    # Expected p of the pick under softmax(p / 0.1) over the qualifying candidates.
    threshold = 0.4 - 0.02 * np.ceil(np.maximum(0.4 - best, 0.0) / 0.02 - 1e-6)
    weights = np.where(scores >= threshold[:, None] - 1e-6, np.exp(scores / 0.1), 0.0)
    expected = (weights * scores).sum(1) / weights.sum(1)
    assert p.mean() == pytest.approx(expected.mean(), abs=0.01)
    # Not the argmax rule: the pick is below the best candidate often.
    assert np.mean(p < best - 1e-6) > 0.3


def test_a_matching_stopped_by_the_iteration_cap_is_logged_as_not_converged():
    """curriculum/auction_converged is 0 when auction_max_iters stops the auction (its
    assignment is then completed greedily), 1 when it finishes."""
    capped = dataclasses.replace(CFG, auction_max_iters=1)
    goals, m = _propose(capped, ENV, DIST, NO_PARAMS)(POOL, 6, jnp.zeros(2), jax.random.key(0))
    assert float(m["curriculum/auction_converged"]) == 0.0
    assert goals.shape == (4, 2)
    _, m = RUN(POOL, 6, jnp.zeros(2), jax.random.key(0))
    assert float(m["curriculum/auction_converged"]) == 1.0


def test_rarity_weights_are_minus_w_log_kde_density_by_hand():
    """Gaussian KDE with bandwidth 5% of the goal extent (36 -> 1.8 units per coordinate):
    an outcome among many visited states weighs less than a lone one, by w * the log
    density ratio, computed here in numpy."""
    visited = np.asarray([[0.0, 0.0]] * 9 + [[10.0, 0.0]], np.float32)
    outcomes = np.asarray([[0.0, 0.0], [10.0, 0.0], [-15.0, 15.0]], np.float32)
    got = np.asarray(cur.rarity_log_weights(ENV, jnp.asarray(outcomes), jnp.asarray(visited), 2.0))
    h = 0.05 * 36.0
    sq = (((outcomes[:, None] - visited[None]) / h) ** 2).sum(-1)
    want = -2.0 * np.log(np.exp(-0.5 * sq.astype(np.float64)).sum(1))
    np.testing.assert_allclose(got[:2], want[:2], rtol=1e-5, atol=1e-5)
    assert got[0] < got[1] < got[2]  # crowded, then 1 of 10 visits, then never visited
    np.testing.assert_allclose(got[1] - got[0], 2.0 * np.log(9.0), rtol=1e-4)
