"""Curriculum goals by bipartite matching (SPEC §1, §5, §6; paper Eq. 6-7, Alg. 1).

K goal slots (desired examples, one mode after another) are matched to K distinct
trajectories of the most recent P episodes. The cost of an edge (slot j, trajectory k)
is min_t w(phi(s_kt), g_j+), with w(x, g+) = BCE(p_pseudo(x; g+); y = p_pseudo(g+; g+))
(Eq. 7); the argmin state, plus noise, becomes curriculum goal j. All functions are
pure and jittable with fixed shapes. The goal after a reached one (SPEC §6) is
`goal_switch`'s.
"""

from __future__ import annotations

from typing import Callable

import jax
import jax.numpy as jnp
from flax import struct

from d2c_jax.config import CurriculumConfig
from d2c_jax.core import types
from d2c_jax.core.types import Metrics
from d2c_jax.curricula import matching
from d2c_jax.curricula.classifier import Classifier, log_p_pseudo, p_pseudo
from envs import GoalEnv, goal_distance

# value_fn(goals (P, T', d)) -> (P, T') V(s0, g) = min_i Q_i(s0, pi(s0, g), g)
ValueFn = Callable[[jax.Array], jax.Array]
# goal_value_fn(obs (P, T', o), goal (d,)) -> (P, T') V(s, g) = min_i Q_i(s, pi(s, g), g)
GoalValueFn = Callable[[jax.Array, jax.Array], jax.Array]


@struct.dataclass
class CurriculumHyperparams:
    """The curriculum's shape-keeping hyperparameters as traced values (leading run axis
    when vmapped), so that a sweep can vmap over them (issue 13)."""

    goal_noise: jax.Array  # () float32 half-width c of the goals' U[-c, c] noise (SPEC §5)
    goal_value_weight: jax.Array  # () float32 beta of the value term of the edge costs
    post_success_range: jax.Array  # () float32 r of the post-success candidates (SPEC §6)
    post_success_threshold: jax.Array  # () float32 "outpace": the p a candidate needs
    post_success_relax: jax.Array  # () float32 "outpace": the threshold's relaxing step
    post_success_temperature: jax.Array  # () float32 "outpace": softmax temperature


def hyperparams(cfg: CurriculumConfig) -> CurriculumHyperparams:
    """The config's values as float32 scalars (host side)."""
    return types.float32_scalars(CurriculumHyperparams, cfg)


def _noise_mask(env: GoalEnv) -> jax.Array:
    """(goal_dim,) 1 where goal noise applies, 0 where a coordinate is pinned."""
    return jnp.asarray(env.goal_noise_mask, jnp.float32)


def desired_examples(env: GoalEnv, n_per_mode: int, key: jax.Array) -> jax.Array:
    """The desired examples of SPEC §1: mode point + N(0, (radius/2)^2) * mask, clipped.

    Returns:
      (n_modes, n_per_mode, goal_dim) examples.
    """
    modes = jnp.asarray(env.goal_points, jnp.float32)  # (n_modes, d)
    noise = jax.random.normal(key, (modes.shape[0], n_per_mode, modes.shape[1]))
    examples = modes[:, None, :] + noise * (env.success_radius / 2.0) * _noise_mask(env)
    return env.clip_goal(examples)


def goal_slots(env: GoalEnv, n_slots: int, key: jax.Array) -> jax.Array:
    """Slots g_j+ of SPEC §5: mode j mod n_modes plus N(0, (radius/2)^2) * mask, clipped.

    Returns:
      (n_slots, goal_dim) slot goals (fresh draws of the desired-example distribution).
    """
    modes = jnp.asarray(env.goal_points, jnp.float32)
    centres = modes[jnp.arange(n_slots) % modes.shape[0]]  # (K, d)
    noise = jax.random.normal(key, centres.shape)
    return env.clip_goal(centres + noise * (env.success_radius / 2.0) * _noise_mask(env))


def subsample(pool_ag: jax.Array, stride: int, tail_fraction: float = 1.0) -> jax.Array:
    """Every `stride`-th step plus the final one (SPEC §5): (P, T, d) -> (P, T', d).

    With tail_fraction < 1 only the last that fraction of each trajectory (plus its final
    state) is kept: OUTPACE scores the last 50%, where an episode has got somewhere.
    """
    t = pool_ag.shape[1]
    first = int(round(t * (1.0 - tail_fraction)))
    steps = sorted(set(range(first, t, stride)) | {t - 1})  # static: T is known at trace time
    return pool_ag[:, jnp.asarray(steps)]


def moved(pool_ag: jax.Array, min_move: float) -> jax.Array:
    """(P,) bool: phi moved more than `min_move` from the first to the last state.

    OUTPACE keeps barely-moving (warm-up) episodes out of its trajectory pool.
    """
    return goal_distance(pool_ag[:, 0], pool_ag[:, -1]) > min_move


# KDE bandwidth of `rarity_log_weights` per goal coordinate, as a fraction of the goal
# bounds' extent: 1.8 maze units (under half a 4-unit cell), 3 cm on the Sawyer table.
RARITY_BANDWIDTH = 0.05


def rarity_log_weights(
    env: GoalEnv, outcomes: jax.Array, visited: jax.Array, rarity: float
) -> jax.Array:
    """-rarity * log density(outcome) under a Gaussian KDE of visited achieved goals.

    Weights for drawing episodes by how rarely their outcome was visited (MEGA's
    minimum-density goals, Pitis et al. 2020, in soft form): with the archive drawn
    proportional to exp of these, an episode that ended where the agent seldom goes is
    density^-rarity times as likely as one ending where it often goes. Only visitation
    counts, so nothing about walls or the desired outcomes is used.

    Args:
      env: the environment (its goal bounds set the bandwidth, `RARITY_BANDWIDTH`).
      outcomes: (N, d) final achieved goals of the episodes.
      visited: (M, d) achieved goals of random buffer states (the KDE's points).
      rarity: the exponent w >= 0.
    Returns:
      (N,) log-weights (up to a constant).
    """
    span = jnp.asarray(env.goal_high, jnp.float32) - jnp.asarray(env.goal_low, jnp.float32)
    scale = RARITY_BANDWIDTH * jnp.where(span > 0, span, 1.0)  # (d,); pinned coordinates: 1
    diff = (outcomes[:, None, :] - visited[None, :, :]) / scale  # (N, M, d)
    log_density = jax.scipy.special.logsumexp(-0.5 * jnp.sum(diff**2, axis=-1), axis=1)
    return -rarity * log_density


def matched_distance(goals: jax.Array, desired: jax.Array) -> jax.Array:
    """Paper §5.1's curriculum distance: mean L2 after an optimal matching of the two sets.

    goals (K, d), desired (K, d) -> (): each goal is paired with a distinct desired example
    so that the summed distance is least (Figs. 4 and 9), so a curriculum that covers one
    mode only stays far from the others' examples.
    """
    dist = goal_distance(goals[:, None, :], desired[None, :, :])  # (K, K)
    cols = matching.auction(dist)
    return dist[jnp.arange(goals.shape[0]), cols].mean()


def soft_bce(log_p: jax.Array, log_q: jax.Array, y: jax.Array) -> jax.Array:
    """Binary cross-entropy against a soft target y, from log p and log(1 - p) (elementwise).

    Taking logs rather than p keeps far-away states ordered by how desired-like they look
    even where p itself underflows (see `classifier.log_p_pseudo`).
    """
    return -(y * log_p + (1.0 - y) * log_q)


def cost_matrix(
    net: Classifier,
    params: dict,
    slots: jax.Array,
    pool_ag: jax.Array,
    stride: int,
    value_fn: ValueFn | None = None,
    value_scale: float = 0.0,
    tail_fraction: float = 1.0,
    pool_obs: jax.Array | None = None,
    goal_value_fn: GoalValueFn | None = None,
    goal_value_scale: float = 0.0,
) -> tuple[jax.Array, jax.Array]:
    """Eq. 7 edge costs and their argmin states.

    cost[j, k] = min_t w(phi(s_kt), g_j+), w(x, g+) = BCE(p_pseudo(x; g+), p_pseudo(g+; g+)),
    over the subsampled steps of trajectory k. With `value_fn` (the "+Value" ablation,
    appendix C.2), w' = w - value_scale * V(s0, phi(s_kt)). With `goal_value_fn`, also
    w' = w - goal_value_scale * V(s_kt, g_j+): of two equally novel candidates, the one the
    critic rates nearer (in time) to slot j's desired example.

    Args:
      net: classifier module; params: its parameters.
      slots: (K, d) slot goals g_j+.
      pool_ag: (P, T, d) achieved-goal trajectories of the pool.
      stride: subsampling stride.
      value_fn: optional V over goals, (P, T', d) -> (P, T').
      value_scale: weight of V, (1 - gamma) for the "+Value" ablation.
      tail_fraction: score only the last this fraction of each trajectory (`subsample`).
      pool_obs: (P, T, o) observations of the pool states; needed by `goal_value_fn`.
      goal_value_fn: optional V(s, g) over observations and one goal.
      goal_value_scale: weight of V(s, g_j+).
    Returns:
      cost (K, P) and candidates (K, P, d), the argmin state of each edge.
    """
    traj = subsample(pool_ag, stride, tail_fraction)  # (P, T', d)
    traj_obs = None if goal_value_fn is None else subsample(pool_obs, stride, tail_fraction)
    y = p_pseudo(net, params, slots, slots)  # (K,) soft target p_pseudo(g+; g+)
    value = None if value_fn is None else value_scale * value_fn(traj)  # (P, T')
    pool_index = jnp.arange(traj.shape[0])

    def one_slot(slot_and_target):
        """Row j of the cost matrix: (d,), () -> cost (P,), candidates (P, d)."""
        slot, target = slot_and_target
        log_p, log_q = log_p_pseudo(net, params, traj, slot)  # (P, T')
        w = soft_bce(log_p, log_q, target)
        if value is not None:
            w = w - value
        if goal_value_fn is not None:
            w = w - goal_value_scale * goal_value_fn(traj_obs, slot)
        best = jnp.argmin(w, axis=-1)  # (P,)
        return w[pool_index, best], traj[pool_index, best]

    # One slot at a time: a slot's classifier activations (P * T' rows) stay in cache,
    # all K slots' at once do not; measured 2.3x faster on the quick preset's 2x128 net.
    cost, candidates = jax.lax.map(one_slot, (slots, y))
    return cost, candidates


def uniform_noise(env: GoalEnv, key: jax.Array, shape: tuple[int, ...], c: float) -> jax.Array:
    """U[-c, c] * goal_noise_mask of the given shape (..., d)."""
    return jax.random.uniform(key, shape, minval=-c, maxval=c) * _noise_mask(env)


def warmup_goals(env: GoalEnv, start_goal: jax.Array, n_slots: int, key: jax.Array) -> jax.Array:
    """Before the pool is full: start position + N(0, radius^2) * mask, clipped: (K, d)."""
    noise = jax.random.normal(key, (n_slots, start_goal.shape[-1]))
    return env.clip_goal(start_goal + noise * env.success_radius * _noise_mask(env))


def pool_full(pool_valid: jax.Array) -> jax.Array:
    """() bool: all P pool entries hold episodes; pool_valid is (P,) bool."""
    return jnp.all(pool_valid)


# The metrics `propose` returns (held between matchings in the TrainState).
METRIC_KEYS = (
    "curriculum/distance",
    "curriculum/slot_distance",
    "curriculum/matched_cost",
    "curriculum/pool_full",
    "curriculum/auction_converged",
)

# Cost of a pool trajectory that may not be matched (barely moved): above any real cost,
# so the auction takes it only when fewer usable trajectories than slots exist.
_UNUSABLE_COST = 1e4


def propose(
    cfg: CurriculumConfig,
    env: GoalEnv,
    net: Classifier,
    params: dict,
    pool_ag: jax.Array,
    pool_valid: jax.Array,
    start_goal: jax.Array,
    key: jax.Array,
    value_fn: ValueFn | None = None,
    *,
    gamma: float,
    pool_obs: jax.Array | None = None,
    goal_value_fn: GoalValueFn | None = None,
    hp: CurriculumHyperparams | None = None,
) -> tuple[jax.Array, Metrics]:
    """K curriculum goals (SPEC §5, Eq. 6-7).

    Variant "d2c": match slots to distinct pool trajectories by the auction on Eq. 7 costs;
    goal j = matched candidate + U[-c, c] * mask (c = the goal noise), clipped. "value": the same
    with w' = w - (1 - gamma) V(s0, phi(s)). "none": the slots themselves (fresh desired
    examples). With a `goal_value_fn`, each edge cost also loses beta (1 - gamma)
    V(s, g_j+) (`cost_matrix`; beta = hp.goal_value_weight). Until all pool entries are valid,
    "d2c"/"value" return the warm-up goals.
    Trajectories that moved at most `cfg.pool_min_move` are matched only if nothing else
    is left. The matching always runs and `jnp.where` selects (no `lax.cond`): under vmap
    over seeds a cond would run both branches anyway, and an empty pool gives a constant
    cost, which the auction returns at once.

    Args:
      cfg: curriculum config (K = cfg.n_slots).
      env: the environment.
      net: classifier module; params: its parameters.
      pool_ag: (P, T, d) achieved goals of the pool episodes (recent, then archived).
      pool_valid: (P,) bool, which pool entries hold episodes.
      start_goal: (d,) phi of the start state (warm-up centre), computed on the host.
      key: PRNG key.
      value_fn: V over goals (P, T', d) -> (P, T'); required by variant "value".
      gamma: SAC discount (`SACConfig.gamma`), for the (1 - gamma) scale of the value
        terms ("+Value" and beta).
      pool_obs: (P, T, o) observations of the pool states; needed with goal_value_fn.
      goal_value_fn: V(s, g) over observations and one goal; None leaves the value term
        out (the trainer passes one when some run has beta > 0).
      hp: the traced c and beta (the trainer's `TrainState.hparams.curriculum`); None:
        `hyperparams(cfg)`.
    Returns:
      goals (K, d) and metrics {"curriculum/distance" (paper §5.1, `matched_distance`),
      "curriculum/slot_distance" (each goal to its own slot), "curriculum/matched_cost",
      "curriculum/pool_full", "curriculum/auction_converged"}.
    """
    hp = hyperparams(cfg) if hp is None else hp
    key_slots, key_noise, key_warm = jax.random.split(key, 3)
    slots = goal_slots(env, cfg.n_slots, key_slots)  # (K, d)
    if cfg.variant == "none":
        goals, full, matched_cost = slots, jnp.ones((), bool), jnp.zeros(())
        converged = jnp.ones((), bool)
    else:
        if cfg.variant == "value" and value_fn is None:
            raise ValueError("curriculum variant 'value' needs a value_fn")
        fn = value_fn if cfg.variant == "value" else None
        if goal_value_fn is not None and pool_obs is None:
            raise ValueError("a goal_value_fn needs pool_obs")
        cost, candidates = cost_matrix(
            net, params, slots, pool_ag, cfg.cost_stride, fn,
            value_scale=1.0 - gamma, tail_fraction=cfg.pool_tail_fraction,
            pool_obs=pool_obs, goal_value_fn=goal_value_fn,
            goal_value_scale=hp.goal_value_weight * (1.0 - gamma),
        )  # fmt: skip
        noise = uniform_noise(env, key_noise, slots.shape, hp.goal_noise)  # SPEC §5's eps
        goals, matched_cost, full, converged = assign_goals(
            cfg, env, cost, candidates, pool_ag, pool_valid, start_goal, noise, key_warm
        )
    return goals, proposal_metrics(goals, slots, matched_cost, full, converged)


def assign_goals(
    cfg: CurriculumConfig,
    env: GoalEnv,
    cost: jax.Array,
    candidates: jax.Array,
    pool_ag: jax.Array,
    pool_valid: jax.Array,
    start_goal: jax.Array,
    noise: jax.Array,
    key_warm: jax.Array,
) -> tuple[jax.Array, jax.Array, jax.Array, jax.Array]:
    """The end every matching curriculum shares (D2C, HGG, OUTPACE): pool trajectories
    that moved at most `cfg.pool_min_move` get `_UNUSABLE_COST`; the auction gives each
    slot a distinct trajectory; goal j = its edge's candidate + noise, clipped; until all
    pool entries hold episodes, the warm-up goals.

    Args:
      cost: (K, P) edge costs; candidates: (K, P, d) each edge's state.
      pool_ag: (P, T, d) the pool's achieved goals; pool_valid: (P,) bool.
      start_goal: (d,) the warm-up centre; noise: (K, d) added to the matched states.
    Returns:
      goals (K, d), the mean matched cost () (0 during warm-up), full () bool and the
      auction's converged () bool.
    """
    if cfg.pool_min_move > 0:
        cost = jnp.where(moved(pool_ag, cfg.pool_min_move)[None], cost, _UNUSABLE_COST)
    solved = matching.auction_solve(cost, max_iters=cfg.auction_max_iters)
    rows, cols = jnp.arange(cfg.n_slots), solved.assignment  # (K,) distinct columns
    full = pool_full(pool_valid)
    warm = warmup_goals(env, start_goal, cfg.n_slots, key_warm)
    goals = jnp.where(full, env.clip_goal(candidates[rows, cols] + noise), warm)
    matched_cost = jnp.where(full, cost[rows, cols].mean(), 0.0)
    return goals, matched_cost, full, solved.converged


def start_to_desired_distance(env: GoalEnv, start_goal: jax.Array) -> jax.Array:
    """() the largest distance from the start's achieved goal to a mode point: HGG's and
    OUTPACE's D (both estimate it as the largest initial goal distance over 1000 resets;
    our start is fixed and the desired examples are the mode points plus noise)."""
    modes = jnp.asarray(env.goal_points, jnp.float32)
    return jnp.max(goal_distance(modes, start_goal[None]))


def proposal_metrics(goals: jax.Array, slots: jax.Array, matched_cost, full, converged) -> Metrics:
    """The `METRIC_KEYS` metrics of goals (K, d) proposed for slots (K, d), each () float32.

    Args:
      goals, slots: (K, d) the proposed goals and the slots (desired examples) they serve.
      matched_cost: () mean cost of the matched edges (0 without a matching).
      full: () bool the pool was full (the goals are matched, not warm-up goals).
      converged: () bool the auction converged.
    """
    return {
        # Paper §5.1, Figs. 4 and 9: how far the curriculum still is from the desired outcomes.
        "curriculum/distance": matched_distance(goals, slots),
        "curriculum/slot_distance": goal_distance(goals, slots).mean(),
        "curriculum/matched_cost": jnp.asarray(matched_cost, jnp.float32),
        "curriculum/pool_full": jnp.asarray(full, jnp.float32),
        # 0 when the auction hit its iteration cap (its assignment was then completed
        # greedily): a matching that is not optimal must show.
        "curriculum/auction_converged": jnp.asarray(converged, jnp.float32),
    }
