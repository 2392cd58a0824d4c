"""The episode loop: `num_envs` parallel episodes, one step vmapped over envs, scanned over time.

`run` is the one loop; everything that plays episodes is built on it:

- `collect` (training, SPEC §2 step 2): env i is conditioned on curriculum goal i mod K;
  when an env reaches its current goal it switches to a new one (SPEC §6, Alg. 1 lines
  8-9) through `env.set_goal`, and, once the curriculum goal was reached, optionally also
  every `switch_every` steps (OUTPACE's random walk). Training episodes never end early.
  Each transition keeps the goal that was active when its action was taken.
- `evaluate` (SPEC §7): one episode per (mode, repeat), no goal switching.
- `trajectories` (rendering, the demo): the states an episode visits, reset state first.

Key streams: episode i of `run(..., key)` uses `split(key, n)[i]`, split into (reset,
steps); the step key t = `split(steps, H)[t]` is split once more, the policy getting the
first half and the goal switch the second. So an episode does not depend on how many
others run beside it, and `collect`, `evaluate` and `trajectories` given the same goals
and key play the same episodes.
"""

from __future__ import annotations

from typing import Any, Callable, NamedTuple

import jax
import jax.numpy as jnp

from envs import EnvState, GoalEnv, goal_distance

# policy(obs (obs_dim,), goal (goal_dim,), key) -> action (action_dim,)
Policy = Callable[[jax.Array, jax.Array, jax.Array], jax.Array]
# next_goal(achieved_goal (goal_dim,), key) -> goal (goal_dim,)
GoalSwitch = Callable[[jax.Array, jax.Array], jax.Array]
# record(before, action (action_dim,), after) -> pytree: what `run` keeps of one env's
# step; `before` is the state the action was taken in, `after` the state it led to, with
# the goal still the one pursued (any goal switch comes after the record).
Record = Callable[[EnvState, jax.Array, EnvState], Any]


class Episodes(NamedTuple):
    """A batch of whole episodes, the layout the replay buffer inserts."""

    obs: jax.Array  # (n_envs, H + 1, obs_dim)
    achieved_goal: jax.Array  # (n_envs, H + 1, goal_dim)
    action: jax.Array  # (n_envs, H, action_dim)
    goal: jax.Array  # (n_envs, H, goal_dim), the goal active at each step
    success: jax.Array  # (n_envs, H) bool, goal reached after the step
    walk_start: jax.Array  # (n_envs,) int32 first step after the curriculum goal was reached


class Trace(NamedTuple):
    """The states of a batch of episodes, reset state first: what drawing them needs
    (the fields of `viewing.render.Trajectory`). T is the number of steps."""

    qpos: jax.Array  # (n, T + 1, nq)
    mocap_pos: jax.Array  # (n, T + 1, nmocap, 3)
    goal: jax.Array  # (n, T + 1, goal_dim), the goal pursued in each state
    success: jax.Array  # (n, T + 1) bool, that goal reached in this state
    achieved_goal: jax.Array  # (n, T + 1, goal_dim) phi(s)


def random_policy(action_dim: int) -> Policy:
    """Uniform random actions in [-1, 1] (the warm-up, the demo)."""

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


def stayed_at_start(achieved_goal: jax.Array, radius: float) -> jax.Array:
    """Whether each episode's achieved goal never left the ball of `radius` around its first
    one: (..., T + 1, goal_dim) -> (...,) bool.

    With radius = the success radius this flags episodes that could not have reached any
    goal farther than one radius (the ant standing still, the Sawyer peg never moved): the
    signal behind a policy that stops trying for goals it cannot reach.
    """
    farthest = goal_distance(achieved_goal, achieved_goal[..., :1, :]).max(axis=-1)
    return farthest <= radius


# --- the loop ---------------------------------------------------------------------------


def episode_keys(env_keys: jax.Array, steps: int) -> tuple[jax.Array, jax.Array]:
    """(reset keys (n_envs,), step keys (steps, n_envs)) of `run_with_env_keys`.

    Env i's keys come from its own key `env_keys[i]` alone (in `run`, `split(key,
    n_envs)[i]`), split into (reset, steps), the latter into `steps` step keys: the same
    stream as a per-env episode loop, so any subset of the envs can be played apart.
    """
    split = jax.vmap(jax.random.split)
    key_reset, key_steps = jnp.moveaxis(split(env_keys), 1, 0)
    step_keys = jax.vmap(lambda k: jax.random.split(k, steps))(key_steps)  # (n, steps)
    return key_reset, jnp.moveaxis(step_keys, 1, 0)


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


def _make_step(
    env: GoalEnv, policy: Policy, next_goal: GoalSwitch | None, switch_every: int, record: Record
):
    """The scan body of `run`: (carry, keys (n_envs,)) -> (carry, records (n_envs, ...)).

    carry = (states (n_envs,), walking (n_envs,) bool past the first success, since
    (n_envs,) int32 steps since the last goal switch).
    """
    split = jax.vmap(jax.random.split)

    def step(carry, keys):
        states, walking, since = carry
        key_act, key_goal = jnp.moveaxis(split(keys), 1, 0)
        actions = jax.vmap(policy)(states.obs, states.goal, key_act)
        after = jax.vmap(env.step)(states, actions)
        out = jax.vmap(record)(states, actions, after)
        if next_goal is None:
            return (after, walking, since), out
        reached = after.success
        # SPEC §6: after success, pick a new goal for the following steps; OUTPACE also
        # every `switch_every` steps of the random walk, so no goal holds the agent long.
        due = walking & (since + 1 >= switch_every) if switch_every > 0 else False
        switch = reached | due
        after = _switch_goals(env, next_goal, after, switch, key_goal)
        return (after, walking | reached, jnp.where(switch, 0, since + 1)), out

    return step


def run(
    env: GoalEnv,
    policy: Policy,
    goals: jax.Array,
    key: jax.Array,
    *,
    record: Record,
    steps: int | None = None,
    next_goal: GoalSwitch | None = None,
    switch_every: int = 0,
) -> tuple[EnvState, Any]:
    """Plays one episode per goal in parallel: the one episode loop.

    A scan over the steps of a step vmapped over envs (rather than a vmap of per-env
    scans), so that a step where no env switches goals skips the goal choice.

    Args:
      env: the environment.
      policy: action function (see `Policy`); it gets the first half of each step key.
      goals: (n_envs, goal_dim) the goal each episode starts with (`env.reset_with_goal`).
      key: PRNG key; env i plays with `split(key, n_envs)[i]` (see `episode_keys`).
      record: what to keep of each step (see `Record`).
      steps: env steps per episode (default: the horizon H).
      next_goal: post-success goal choice (see `GoalSwitch`); None: goals never change.
      switch_every: with `next_goal`, after the first success also switch goals every
        this many steps (0: only on success).
    Returns:
      (the reset states (n_envs,), the records with leading axes (n_envs, steps)).
    """
    return run_with_env_keys(
        env, policy, goals, jax.random.split(key, goals.shape[0]), record=record,
        steps=steps, next_goal=next_goal, switch_every=switch_every,
    )  # fmt: skip


def run_with_env_keys(
    env: GoalEnv,
    policy: Policy,
    goals: jax.Array,
    env_keys: jax.Array,
    *,
    record: Record,
    steps: int | None = None,
    next_goal: GoalSwitch | None = None,
    switch_every: int = 0,
) -> tuple[EnvState, Any]:
    """`run` with each env's key given (n_envs,): `run(..., key)` is this with
    `split(key, n_envs)`."""
    steps = env.horizon if steps is None else steps
    num_envs = goals.shape[0]
    key_reset, step_keys = episode_keys(env_keys, steps)
    first = jax.vmap(env.reset_with_goal)(key_reset, goals)
    step = _make_step(env, policy, next_goal, switch_every, record)
    carry = (first, jnp.zeros(num_envs, bool), jnp.zeros(num_envs, jnp.int32))
    _, records = jax.lax.scan(step, carry, step_keys)
    env_major = lambda x: jnp.moveaxis(x, 0, 1)  # noqa: E731  (steps, n, ...) -> (n, steps, ...)
    return first, jax.tree.map(env_major, records)


def _prepend(first: jax.Array, rest: jax.Array) -> jax.Array:
    """(n, ...) and (n, T, ...) -> (n, T + 1, ...): the reset state's value first."""
    return jnp.concatenate([first[:, None], rest], axis=1)


# --- what plays episodes ----------------------------------------------------------------


def _transition(before: EnvState, action: jax.Array, after: EnvState) -> tuple:
    """`collect`'s record: (obs', achieved goal', action, goal pursued, success')."""
    return after.obs, after.achieved_goal, action, before.goal, after.success


def collect(
    env: GoalEnv,
    policy: Policy,
    next_goal: GoalSwitch | None,
    curriculum_goals: jax.Array,
    num_envs: int,
    key: jax.Array,
    switch_every: int = 0,
    max_batch: int | None = None,
) -> Episodes:
    """Runs `num_envs` training episodes in parallel; env i starts with curriculum goal
    i mod K and switches goals after success (`run` with `next_goal`; None keeps them).

    Args:
      env: the environment.
      policy: action function (see `Policy`).
      next_goal: post-success goal choice (see `GoalSwitch`); None: no switching.
      curriculum_goals: (K, goal_dim) the curriculum goals.
      num_envs: number of parallel episodes.
      key: PRNG key.
      switch_every: after the first success, also switch goals every this many steps
        (0: only on success).
      max_batch: episodes played at once at most (`in_batches`, the same episodes;
        `max_episodes_per_call`); None: all in one call.
    Returns:
      Episodes with leading axis num_envs.
    """
    k = curriculum_goals.shape[0]
    goals = curriculum_goals[jnp.arange(num_envs) % k]
    play = lambda g, keys: run_with_env_keys(  # noqa: E731
        env, policy, g, keys, record=_transition, next_goal=next_goal, switch_every=switch_every
    )
    first, (obs, ag, action, goal, success) = in_batches(
        play, goals, jax.random.split(key, num_envs), max_batch
    )
    return Episodes(
        obs=_prepend(first.obs, obs),
        achieved_goal=_prepend(first.achieved_goal, ag),
        action=action,
        goal=goal,
        success=success,
        walk_start=walk_start(success),
    )


# Env states stepped in one call at most on XLA:CPU, counting every run vmapped together.
# MJX's Newton solver (Ant, Sawyer) factors a batch of matrices with jaxlib's LAPACK
# Cholesky. jaxlib 0.10.2 splits a large batch into tasks on XLA's intra-op thread pool
# and blocks until they finish, so as many such factorizations at once as the pool has
# threads (2 here) wait forever for each other's tasks. Measured on 2 cores: two
# independent factorizations of 14x14 matrices (the ant's) per scan step finish at a
# batch of 200, slow down at 256-300 and hang at 384; an Ant evaluation of 400 episodes
# hangs, of 200 finishes (benchmarks/RESULTS.md, stop 75).
MAX_CPU_ENV_BATCH = 200


def max_episodes_per_call(platform: str, num_runs: int) -> int | None:
    """Episodes one call of the episode loop may play per run when `num_runs` runs are
    vmapped together on `platform` (`jax.default_backend()`): on CPU `MAX_CPU_ENV_BATCH`
    shared by the runs (at least 1), elsewhere no cap (None)."""
    if platform != "cpu":
        return None
    return max(1, MAX_CPU_ENV_BATCH // num_runs)


def in_batches(play, goals: jax.Array, env_keys: jax.Array, max_batch: int | None):
    """`play(goals, env_keys)` on (n, ...) inputs: one call when n <= max_batch (or
    max_batch is None), else `lax.map` over batches of max_batch rows (the last padded by
    repeating its final row; the padding's outputs are dropped). Each episode keeps its
    own key, so its outcome does not depend on the batching."""
    n = goals.shape[0]
    if max_batch is None or n <= max_batch:
        return play(goals, env_keys)
    n_batches = -(-n // max_batch)
    pad = n_batches * max_batch - n
    batched = [
        jnp.concatenate([x, jnp.repeat(x[-1:], pad, axis=0)]).reshape(
            (n_batches, max_batch) + x.shape[1:]
        )
        for x in (goals, env_keys)
    ]
    out = jax.lax.map(lambda args: play(*args), tuple(batched))
    return jax.tree.map(lambda x: x.reshape((n_batches * max_batch,) + x.shape[2:])[:n], out)


def success_rates(
    env: GoalEnv,
    policy: Policy,
    goals: jax.Array,
    episodes_per_goal: int,
    key: jax.Array,
    max_batch: int | None = None,
) -> jax.Array:
    """(n_goals,) share of `episodes_per_goal` episodes per goal that reach it: SPEC §7's
    episodes (from the start state with its reset noise, no goal switching; success =
    within the radius at any step) for any goals (n_goals, goal_dim).

    Episode i (goal i // episodes_per_goal) uses `split(key, n)[i]`. `policy` should be
    deterministic (tanh of the mean): then its key does not matter. At most `max_batch`
    episodes are played at once (`in_batches`; None: all in one call; on a CPU pass
    `max_episodes_per_call`, as the agent does).
    """
    repeated = jnp.repeat(goals, episodes_per_goal, axis=0)  # (n_goals * n, goal_dim)
    success = in_batches(
        lambda g, k: run_with_env_keys(env, policy, g, k, record=_success_of)[1],
        repeated, jax.random.split(key, repeated.shape[0]), max_batch,
    )  # fmt: skip
    hit = success.any(axis=1).astype(jnp.float32)  # (n_goals * n,)
    return hit.reshape(goals.shape[0], episodes_per_goal).mean(axis=1)


def _success_of(before: EnvState, action: jax.Array, after: EnvState) -> jax.Array:
    """The `Record` of `success_rates`: success after each step."""
    return after.success


def evaluate(
    env: GoalEnv,
    policy: Policy,
    episodes_per_mode: int,
    key: jax.Array,
    max_batch: int | None = None,
) -> jax.Array:
    """SPEC §7: success rate per mode, (n_modes,): `success_rates` with the goal = each
    mode point exactly, at most `max_batch` episodes at a time."""
    goals = jnp.asarray(env.goal_points)
    return success_rates(env, policy, goals, episodes_per_mode, key, max_batch)


def _trace_point(state: EnvState) -> Trace:
    """The Trace fields of (a batch of) states: no full mjx.Data per step."""
    data = state.data
    return Trace(data.qpos, data.mocap_pos, state.goal, state.success, state.achieved_goal)


def trajectories(
    env: GoalEnv,
    policy: Policy,
    goals: jax.Array,
    key: jax.Array,
    *,
    steps: int | None = None,
    next_goal: GoalSwitch | None = None,
    switch_every: int = 0,
) -> Trace:
    """The states of one episode per goal (rendering, the demo), reset state first.

    Args:
      goals: (n, goal_dim) the goal of each episode.
      steps: env steps per episode (default: the horizon H).
      next_goal, switch_every: goal switching as in `collect` (default: none). A state's
        goal is the one pursued when it was reached (a switch shows from the next state).
      env, policy, key: as in `run`; the same goals and key give `collect`'s episodes.
    Returns:
      Trace with leading axes (n, steps + 1).
    """
    goals = jnp.asarray(goals, jnp.float32)
    first, rest = run(
        env,
        policy,
        goals,
        key,
        record=lambda before, action, after: _trace_point(after),
        steps=steps,
        next_goal=next_goal,
        switch_every=switch_every,
    )
    return jax.tree.map(_prepend, _trace_point(first), rest)
