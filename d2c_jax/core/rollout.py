"""Episode collection: `num_envs` parallel episodes, vmapped over envs, scanned over time.

SPEC §2 step 2: env i is conditioned on curriculum goal i mod K; when an env reaches its
current goal it switches to a new one (SPEC §6, Alg. 1 lines 8-9) through `env.set_goal`,
and, once the curriculum goal was reached, optionally also every `switch_every` steps
(OUTPACE's random walk). Training episodes never end early. Each transition keeps the
goal that was active when its action was taken.
"""

from __future__ import annotations

from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp

from envs import EnvState, GoalEnv

# policy(obs (obs_dim,), goal (goal_dim,), key) -> action (action_dim,)
Policy = Callable[[jax.Array, jax.Array, jax.Array], jax.Array]
# next_goal(achieved_goal (goal_dim,), key) -> goal (goal_dim,)
GoalSwitch = Callable[[jax.Array, jax.Array], jax.Array]


class Episodes(NamedTuple):
    """A batch of whole episodes, the layout the replay buffer inserts."""

    obs: jax.Array  # (n_envs, H + 1, obs_dim)
    achieved_goal: jax.Array  # (n_envs, H + 1, goal_dim)
    action: jax.Array  # (n_envs, H, action_dim)
    goal: jax.Array  # (n_envs, H, goal_dim), the goal active at each step
    success: jax.Array  # (n_envs, H) bool, goal reached after the step
    walk_start: jax.Array  # (n_envs,) int32 first step after the curriculum goal was reached


def random_policy(action_dim: int) -> Policy:
    """Uniform random actions in [-1, 1] (the warm-up)."""

    def policy(obs, goal, key):
        return jax.random.uniform(key, (action_dim,), minval=-1.0, maxval=1.0)

    return policy


def walk_start(success: jax.Array) -> jax.Array:
    """First step of the random walk: one past the first success, H if none: (..., H) -> (...,).

    Steps t < walk_start pursued the curriculum goal; later ones post-success goals.
    """
    horizon = success.shape[-1]
    first = jnp.argmax(success, axis=-1)
    return jnp.where(success.any(axis=-1), first + 1, horizon).astype(jnp.int32)


def _switch_goals(env: GoalEnv, next_goal: GoalSwitch, states: EnvState, switch, keys):
    """States (n_envs,) with a new goal where `switch` (n_envs,) bool; `success` recomputed.

    New goals cost a classifier call per env, so they are computed only at steps where
    some env switches (a real `lax.cond` for one seed; under vmap over seeds it becomes a
    select and costs what it did before).
    """
    new_goals = jax.lax.cond(
        switch.any(),
        lambda: jax.vmap(next_goal)(states.achieved_goal, keys),
        lambda: states.goal,
    )
    goals = jnp.where(switch[:, None], new_goals, states.goal)
    return jax.vmap(env.set_goal)(states, goals)


def collect(
    env: GoalEnv,
    policy: Policy,
    next_goal: GoalSwitch,
    curriculum_goals: jax.Array,
    num_envs: int,
    key: jax.Array,
    switch_every: int = 0,
) -> Episodes:
    """Runs `num_envs` episodes in parallel; env i starts with curriculum goal i mod K.

    A scan over the H steps of a step vmapped over envs (rather than a vmap of per-env
    scans), so that a step where no env switches goals skips the goal choice.

    Args:
      env: the environment.
      policy: action function (see `Policy`).
      next_goal: post-success goal choice (see `GoalSwitch`).
      curriculum_goals: (K, goal_dim) the curriculum goals.
      num_envs: number of parallel episodes.
      key: PRNG key.
      switch_every: after the first success, also switch goals every this many steps
        (0: only on success).
    Returns:
      Episodes with leading axis num_envs.
    """
    k = curriculum_goals.shape[0]
    goals = curriculum_goals[jnp.arange(num_envs) % k]
    split = jax.vmap(jax.random.split)
    key_reset, key_steps = jnp.moveaxis(split(jax.random.split(key, num_envs)), 1, 0)
    states = jax.vmap(env.reset_with_goal)(key_reset, goals)
    # (H, n_envs) step keys: env i's stream is the same as in a per-env episode loop.
    step_keys = jnp.moveaxis(
        jax.vmap(lambda kk: jax.random.split(kk, env.horizon))(key_steps), 1, 0
    )

    def step(carry, keys):
        states, walking, since = carry  # (n,) bool past the first success, (n,) goal age
        key_act, key_goal = jnp.moveaxis(split(keys), 1, 0)
        active_goals = states.goal
        actions = jax.vmap(policy)(states.obs, active_goals, key_act)
        states = jax.vmap(env.step)(states, actions)
        reached = states.success
        # SPEC §6: after success, pick a new goal for the following steps; OUTPACE also
        # every `switch_every` steps of the random walk, so no goal holds the agent long.
        due = walking & (since + 1 >= switch_every) if switch_every > 0 else False
        switch = reached | due
        states = _switch_goals(env, next_goal, states, switch, key_goal)
        out = (states.obs, states.achieved_goal, actions, active_goals, reached)
        return (states, walking | reached, jnp.where(switch, 0, since + 1)), out

    carry = (states, jnp.zeros(num_envs, bool), jnp.zeros(num_envs, jnp.int32))
    _, (obs, ag, actions, active, success) = jax.lax.scan(step, carry, step_keys)
    env_major = lambda x: jnp.moveaxis(x, 0, 1)  # noqa: E731  (H, n, ...) -> (n, H, ...)
    success = env_major(success)
    return Episodes(
        obs=jnp.concatenate([states.obs[:, None], env_major(obs)], axis=1),
        achieved_goal=jnp.concatenate([states.achieved_goal[:, None], env_major(ag)], axis=1),
        action=env_major(actions),
        goal=env_major(active),
        success=success,
        walk_start=walk_start(success),
    )


def evaluate(env: GoalEnv, policy: Policy, episodes_per_mode: int, key: jax.Array) -> jax.Array:
    """SPEC §7: success rate per mode, (n_modes,).

    For each mode point, `episodes_per_mode` episodes from the start state (with its reset
    noise), goal = the mode point exactly, no goal switching; success = within the
    radius at any step. `policy` should be deterministic (tanh of the mean).
    """
    modes = jnp.asarray(env.goal_points)
    goals = jnp.repeat(modes, episodes_per_mode, axis=0)  # (n_modes * n, goal_dim)

    def episode(goal, key):
        key_reset, key_steps = jax.random.split(key)
        state = env.reset_with_goal(key_reset, goal)

        def step(state, key):
            state = env.step(state, policy(state.obs, state.goal, key))
            return state, state.success

        _, success = jax.lax.scan(step, state, jax.random.split(key_steps, env.horizon))
        return success.any()

    keys = jax.random.split(key, goals.shape[0])
    hit = jax.vmap(episode)(goals, keys).astype(jnp.float32)
    return hit.reshape(env.n_modes, episodes_per_mode).mean(axis=1)
