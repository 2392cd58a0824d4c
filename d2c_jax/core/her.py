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
    # n-step returns only (None for one-step; then next_obs is s_{t+1}):
    path_achieved_goal: jax.Array | None = None  # (B, n, goal_dim) phi(s_{t+1..t+n}), H-clamped
    n_taken: jax.Array | None = None  # (B,) int32 n' = min(n, H - t); next_obs is s_{t+n'}


def _n_step_path(state: replay.ReplayState, episode: jax.Array, step: jax.Array, n_step: int):
    """The n steps after each sampled transition, cut at the episode's end.

    Args:
      episode: (B,) int32 slots; step: (B,) int32 t in [0, H).
    Returns:
      phi(s_{t+1..t+n}) (B, n, goal_dim), steps past H repeating phi(s_H); s_{t+n'}
      (B, obs_dim); n' = min(n, H - t) (B,) int32, at least 1.
    """
    n_taken = jnp.minimum(n_step, state.horizon - step)  # (B,)
    later = jnp.minimum(step[:, None] + jnp.arange(1, n_step + 1), state.horizon)  # (B, n)
    path = state.achieved_goal[episode[:, None], later]
    return path, state.obs[episode, step + n_taken], n_taken


def sample_relabelled(
    relabel_prob: jax.Array | float,
    state: replay.ReplayState,
    batch_size: int,
    key: jax.Array,
    walk_fraction: float = 0.0,
    min_distance: float = 0.0,
    random_prob: float = 0.0,
    n_step: int = 1,
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
      n_step: static steps of the return (HERConfig.n_step): > 1 adds each transition's
        next n steps (`path_achieved_goal`, `n_taken`) and sets next_obs to s_{t+n'}.
        1: the one-step transition, and the program is the one-step one.
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
    if n_step == 1:
        return RelabelledTransitions(tr.obs, tr.action, tr.next_obs, tr.next_achieved_goal, goal)
    path, last_obs, n_taken = _n_step_path(state, tr.episode, tr.step, n_step)
    return RelabelledTransitions(
        tr.obs, tr.action, last_obs, tr.next_achieved_goal, goal, path, n_taken
    )


def with_reward(
    tr: RelabelledTransitions,
    reward_fn: RewardFn,
    terminal_fn: RewardFn | None = None,
    gamma: float | None = None,
) -> Batch:
    """The SAC batch of `tr`: reward_fn(phi(s_{t+1}), goal) and its bootstrap mask.

    No terminal on success (SPEC §4, decided): without `terminal_fn` the bootstrap mask is
    1 everywhere; time limits are truncations. A baseline whose own code ends the critic's
    episode at success (OUTPACE) passes terminal_fn(ag_next, goal) -> 1 where s_{t+1} is
    terminal for the relabelled goal, and the mask is 1 - that. Probe tests with other
    terminals build `Batch` directly. With an n-step `tr` (`n_taken` set) the row is the
    n-step return (`_n_step_batch`), discounted by `gamma`, the SAC discount, which such a
    batch requires (a one-step batch ignores it).
    """
    if tr.n_taken is not None:
        if gamma is None:
            raise ValueError("an n-step batch needs the SAC discount gamma")
        return _n_step_batch(tr, reward_fn, terminal_fn, gamma)
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


def _n_step_batch(
    tr: RelabelledTransitions, reward_fn: RewardFn, terminal_fn: RewardFn | None, gamma: float
) -> Batch:
    """The n-step row: reward R = sum_{k<n'} gamma^k alive_k r_k and mask gamma^(n'-1)
    alive_{n'}, so that SAC's target r + gamma mask V(s') is R + gamma^{n'} alive_{n'}
    V(s_{t+n'}); alive_k = prod_{j<k} (1 - terminal_j) (1 without terminals)."""
    n = tr.path_achieved_goal.shape[-2]
    goal = jnp.broadcast_to(tr.goal[..., None, :], tr.path_achieved_goal.shape)  # (B, n, d)
    reward = reward_fn(tr.path_achieved_goal, goal).astype(jnp.float32)  # (B, n)
    taken = jnp.arange(n) < tr.n_taken[..., None]  # (B, n) steps inside the episode
    if terminal_fn is None:
        alive = jnp.ones(reward.shape[:-1] + (n + 1,), jnp.float32)
    else:
        ended = terminal_fn(tr.path_achieved_goal, goal).astype(jnp.float32) * taken
        alive = jnp.cumprod(jnp.concatenate([jnp.ones_like(ended[..., :1]), 1.0 - ended], -1), -1)
    discount = gamma ** jnp.arange(n, dtype=jnp.float32)  # (n,)
    total = jnp.sum(jnp.where(taken, discount * alive[..., :n] * reward, 0.0), axis=-1)
    alive_after = jnp.take_along_axis(alive, tr.n_taken[..., None], axis=-1)[..., 0]
    mask = gamma ** (tr.n_taken - 1).astype(jnp.float32) * alive_after
    return Batch(obs=tr.obs, action=tr.action, reward=total, next_obs=tr.next_obs,
                 goal=tr.goal, mask=mask)  # fmt: skip


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
