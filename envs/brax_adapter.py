"""A `brax.envs.Env` view of a `GoalEnv`, so brax's trainers (SAC, PPO) run on our envs.

    import envs
    from brax.envs.wrappers import training
    from brax.training.agents.sac import train as sac

    env = envs.to_brax(envs.make("medium_maze"))
    make_policy, params, metrics = sac.train(env, num_timesteps=..., episode_length=env.horizon)

What brax sees (one env; brax's `VmapWrapper` adds the batch axis):
  - obs (observation_size,) = concat(env.normalize_obs(obs), env.normalize_goal(goal)):
    the goal-conditioned input of our actor and critic (`envs.base.agent_input`);
  - reward () float32 = 1.0 when `state.success` after the step, else 0.0: the sparse
    success reward (SPEC §4's ablation, the reward of HER and of every sparse baseline);
  - done () float32 = 0 always. SPEC §4: reaching the goal is no terminal, and an episode
    ends only at the horizon, which is a truncation, not a terminal. brax's
    `EpisodeWrapper(episode_length=env.horizon)` sets done = 1 there together with
    `info["truncation"] = 1`, which brax's SAC and PPO read to keep bootstrapping through
    the cut (SAC drops the transition from its critic loss, PPO bootstraps from V). Were
    the adapter to set done itself at the horizon, EpisodeWrapper would record
    truncation = 1 - done = 0 and brax would treat the time limit as a terminal. So pass
    `episode_length=env.horizon` to brax's trainers.
  - metrics {"success": () float32} (brax's wrappers sum it over the episode, so
    `eval/episode_success` counts the steps spent at the goal);
  - pipeline_state: our whole `EnvState` (the `mjx.Data`, obs, achieved and desired goal,
    success), a flax pytree. It must live in pipeline_state, not in info: brax's
    `AutoResetWrapper` restores `pipeline_state` and `obs` (from `info["first_pipeline_state"]`
    and `info["first_obs"]`, leaf by leaf with `jnp.where`) and leaves info alone.

Goals: every `reset(rng)` is `env.reset(rng)`, whose goal is a mode point of the desired
outcomes drawn with the key. brax's `AutoResetWrapper` does not call reset again: it
restarts each env slot from the state that slot's first reset produced (same start
noise, same goal) for the whole run, so a brax training run pursues the `num_envs` goals
drawn at its start (use num_envs >= a few times `env.n_modes`); its evaluator resets
afresh, drawing new goals every evaluation.

Keys: brax passes raw `jax.random.PRNGKey` arrays (uint32 (2,)); its `EpisodeWrapper`
reads the batch shape from `rng.shape[:-1]`, so call the wrapped env with raw keys too.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from brax.envs import base as brax_base

from envs.base import EnvState, GoalEnv, agent_input, agent_input_dim


def sparse_reward(state: EnvState) -> jax.Array:
    """1.0 where the goal is reached (`state.success`), else 0.0: (...,) float32."""
    return state.success.astype(jnp.float32)


class BraxGoalEnv(brax_base.Env):
    """`goal_env` seen through brax's `Env` interface (module docstring: what is where)."""

    def __init__(self, goal_env: GoalEnv):
        self.goal_env = goal_env

    def _state(self, env_state: EnvState, reward: jax.Array) -> brax_base.State:
        return brax_base.State(
            pipeline_state=env_state,
            obs=agent_input(self.goal_env, env_state.obs, env_state.goal),
            reward=reward,
            done=jnp.zeros((), jnp.float32),
            metrics={"success": sparse_reward(env_state)},
        )

    def reset(self, rng: jax.Array) -> brax_base.State:
        """A fresh episode: `goal_env.reset(rng)` (goal = a random mode point); reward 0
        (a reset state ends no transition)."""
        return self._state(self.goal_env.reset(rng), jnp.zeros((), jnp.float32))

    def step(self, state: brax_base.State, action: jax.Array) -> brax_base.State:
        """One env step; action (action_size,) in [-1, 1]. done stays 0 (the horizon is
        EpisodeWrapper's truncation); the wrappers' info and metrics keys are kept."""
        env_state = self.goal_env.step(state.pipeline_state, action)
        new = self._state(env_state, sparse_reward(env_state))
        # Wrappers add their own metrics (EvalWrapper's "reward"): keep every key, as a
        # scan over steps needs the same tree in and out.
        return new.replace(metrics={**state.metrics, **new.metrics}, info=state.info)

    @property
    def observation_size(self) -> int:
        """feat_dim, from the shapes alone (no reset is compiled)."""
        return agent_input_dim(self.goal_env)

    @property
    def action_size(self) -> int:
        return self.goal_env.action_dim

    @property
    def backend(self) -> str:
        return "mjx"

    @property
    def horizon(self) -> int:
        """The episode length H to give brax's trainers as `episode_length`."""
        return self.goal_env.horizon


def to_brax(env: GoalEnv) -> BraxGoalEnv:
    """`env` as a `brax.envs.Env` (see the module docstring); wrap it with
    `brax.envs.wrappers.training.wrap(adapter, episode_length=env.horizon)`, as brax's
    trainers do."""
    return BraxGoalEnv(env)
