"""Hindsight experience replay, "future" strategy (Andrychowicz et al. 2017; SPEC §4).

`relabel` samples transitions from the replay buffer and, with probability
`relabel_prob`, replaces each one's goal by the achieved goal of a later state s_t' of the
same episode, t' uniform in [t + 1, H]; otherwise it keeps the goal that was active at
step t. Optionally (`random_prob` > 0, default off), a share of the transitions gets the
achieved goal of a state drawn uniformly from the whole buffer instead: HER's "random"
strategy (Andrychowicz et al. 2017, §4.5), which pairs a path with goals it never
reached. The reward of every sampled transition is then recomputed by
`reward_fn(ag_next, goal)`, so the sparse reward and D2C's intrinsic reward
p_pseudo(phi(s_{t+1}); g) plug in the same way. Its two halves, `sample_relabelled` and
`with_reward`, let the trainer draw many batches at once and reward each one when it is
used.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from d2c_jax.core import replay
from d2c_jax.core.types import Batch, RewardFn


def sparse_reward_fn(env) -> RewardFn:
    """The sparse reward r = 1[||ag_next - goal|| <= radius] (SPEC §4 ablation)."""

    def reward_fn(ag_next: jax.Array, goal: jax.Array) -> jax.Array:
        return env.is_success(ag_next, goal).astype(jnp.float32)

    return reward_fn


def future_goals(state: replay.ReplayState, episode: jax.Array, step: jax.Array, key: jax.Array):
    """Achieved goals phi(s_t') with t' uniform in [t + 1, H], same episode.

    Args:
      state: the buffer.
      episode: (B,) int32 slots; step: (B,) int32 t in [0, H).
      key: PRNG key.
    Returns:
      (B, goal_dim) future achieved goals.
    """
    future = jax.random.randint(key, step.shape, step + 1, state.horizon + 1)
    return state.achieved_goal[episode, future]


def _with_random_goals(
    state: replay.ReplayState,
    goal: jax.Array,
    future_coin: jax.Array,
    relabel_prob: jax.Array | float,
    random_prob: float,
    key: jax.Array,
) -> jax.Array:
    """goal (B, goal_dim) with HER's "random" goals, phi of states drawn uniformly from
    the buffer, where the future coin (B,) came up tails and a second coin of probability
    random_prob / (1 - relabel_prob) comes up heads: a share random_prob of the batch."""
    key_coin, key_goal = jax.random.split(jax.random.fold_in(key, 1))
    rest = jnp.maximum(1.0 - relabel_prob, 1e-6)  # validation keeps the sum <= 1
    second = jax.random.bernoulli(key_coin, jnp.minimum(random_prob / rest, 1.0), goal.shape[:1])
    random_goals = replay.sample_achieved_goals(state, goal.shape[0], key_goal)
    return jnp.where((~future_coin & second)[:, None], random_goals, goal)


class RelabelledTransitions(NamedTuple):
    """Sampled transitions with their (possibly relabelled) goals, before any reward."""

    obs: jax.Array  # (B, obs_dim) s_t
    action: jax.Array  # (B, action_dim) a_t
    next_obs: jax.Array  # (B, obs_dim) s_{t+1}
    next_achieved_goal: jax.Array  # (B, goal_dim) phi(s_{t+1})
    goal: jax.Array  # (B, goal_dim) the goal after relabelling


def sample_relabelled(
    relabel_prob: jax.Array | float,
    state: replay.ReplayState,
    batch_size: int,
    key: jax.Array,
    walk_fraction: float = 0.0,
    min_distance: float = 0.0,
    random_prob: float = 0.0,
) -> RelabelledTransitions:
    """Samples `batch_size` transitions and relabels their goals ("future" strategy).

    Args:
      relabel_prob: probability of relabelling a transition's goal (HERConfig; a
        traced value in the trainer, so a sweep can vmap over it).
      state: a non-empty replay buffer.
      batch_size: B.
      key: PRNG key.
      walk_fraction: share of the batch from random-walk transitions (`replay.sample`).
      min_distance: a future goal within this distance of phi(s_t) is not used (the
        transition keeps its own goal): where the agent barely moves, such goals, reached
        before acting, are most of HER's (HERConfig.min_future_radii). 0: all are used.
      random_prob: static probability that a transition's goal is the achieved goal of a
        state drawn uniformly from all stored ones ("random" strategy), drawn from the
        transitions the "future" coin left alone, so the three shares are relabel_prob,
        random_prob and 1 - both (HERConfig.random_prob). 0: off, and the program is
        the future-only one.
    Returns:
      RelabelledTransitions with leading axis B.
    """
    key_sample, key_future, key_coin = jax.random.split(key, 3)
    tr = replay.sample(state, batch_size, key_sample, walk_fraction)
    future = future_goals(state, tr.episode, tr.step, key_future)
    coin = jax.random.bernoulli(key_coin, relabel_prob, (batch_size,))  # (B,) "future"
    use_future = coin
    if min_distance > 0:  # static: the default program is unchanged
        achieved_now = state.achieved_goal[tr.episode, tr.step]  # (B, goal_dim) phi(s_t)
        moved = jnp.linalg.norm(future - achieved_now, axis=-1) > min_distance
        use_future = use_future & moved
    goal = jnp.where(use_future[:, None], future, tr.goal)
    if random_prob > 0:  # static: the default program is unchanged
        goal = _with_random_goals(state, goal, coin, relabel_prob, random_prob, key)
    return RelabelledTransitions(tr.obs, tr.action, tr.next_obs, tr.next_achieved_goal, goal)


def with_reward(
    tr: RelabelledTransitions, reward_fn: RewardFn, terminal_fn: RewardFn | None = None
) -> Batch:
    """The SAC batch of `tr`: reward_fn(phi(s_{t+1}), goal) and its bootstrap mask.

    No terminal on success (SPEC §4, decided): without `terminal_fn` the bootstrap mask is
    1 everywhere; time limits are truncations. A baseline whose own code ends the critic's
    episode at success (OUTPACE) passes terminal_fn(ag_next, goal) -> 1 where s_{t+1} is
    terminal for the relabelled goal, and the mask is 1 - that. Probe tests with other
    terminals build `Batch` directly.
    """
    reward = reward_fn(tr.next_achieved_goal, tr.goal).astype(jnp.float32)
    if terminal_fn is None:
        mask = jnp.ones(reward.shape, jnp.float32)
    else:
        mask = 1.0 - terminal_fn(tr.next_achieved_goal, tr.goal).astype(jnp.float32)
    return Batch(
        obs=tr.obs,
        action=tr.action,
        reward=reward,
        next_obs=tr.next_obs,
        goal=tr.goal,
        mask=mask,
    )


def relabel(
    relabel_prob: jax.Array | float,
    state: replay.ReplayState,
    batch_size: int,
    reward_fn: RewardFn,
    key: jax.Array,
    walk_fraction: float = 0.0,
    terminal_fn: RewardFn | None = None,
    min_distance: float = 0.0,
) -> Batch:
    """Samples `batch_size` transitions, relabels their goals and recomputes rewards
    (`sample_relabelled`, then `with_reward`).

    Args:
      relabel_prob, state, batch_size, key, walk_fraction, min_distance: as
        `sample_relabelled`.
      reward_fn: reward_fn(ag_next, goal) -> reward, see `RewardFn`.
      terminal_fn: as `with_reward`; None: no terminals (SPEC §4).
    Returns:
      Batch with leading axis B.
    """
    tr = sample_relabelled(relabel_prob, state, batch_size, key, walk_fraction, min_distance)
    return with_reward(tr, reward_fn, terminal_fn)
