"""The goal-environment contract shared by every d2c_jax environment.

`envs` never imports `d2c_jax`; this module is the only contract between them
(ARCHITECTURE.md, "Contracts"). Every method is a pure function of its inputs, so
it can be jitted and vmapped over a batch of states.
"""

from __future__ import annotations

import abc
from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct
from mujoco import mjx


@struct.dataclass
class EnvState:
    """State of one goal-conditioned episode (batch dimensions lead under vmap)."""

    data: mjx.Data  # the MJX simulation state
    obs: jax.Array  # (obs_dim,) float32
    achieved_goal: jax.Array  # (goal_dim,) float32, phi(s)
    goal: jax.Array  # (goal_dim,) float32, the goal the agent is conditioned on
    success: jax.Array  # () bool, ||achieved_goal - goal|| <= success_radius


class GoalEnv(abc.ABC):
    """Base class: goal interface, success rule and the reset/set_goal plumbing.

    Subclasses set the attributes below in `__init__` (`horizon` as a class constant, so
    that `envs.horizon(name)` reads it without building a model) and implement
    `_reset_data`, `_step_data`, `_observe` and `_achieved_goal`.

    Attributes:
      obs_dim, action_dim, goal_dim: sizes of obs, action and goal vectors.
      horizon: episode length H in env steps.
      success_radius: goal-reaching radius in goal space.
      goal_points: (n_modes, goal_dim) the desired outcome modes.
      goal_low, goal_high: (goal_dim,) goal bounds D_T (also used for normalisation).
    """

    obs_dim: int
    action_dim: int
    goal_dim: int
    horizon: int
    success_radius: float
    goal_points: np.ndarray
    goal_low: np.ndarray
    goal_high: np.ndarray
    # (goal_dim,) 1 where goal noise applies, 0 where a coordinate is pinned
    # (Sawyer push keeps z on the table: SPEC §1, §3, §5, §6).
    goal_noise_mask: np.ndarray

    # --- subclass hooks -------------------------------------------------------
    @abc.abstractmethod
    def _reset_data(self, key: jax.Array) -> mjx.Data:
        """A fresh start state with reset noise."""

    @abc.abstractmethod
    def _step_data(self, data: mjx.Data, action: jax.Array) -> mjx.Data:
        """Advances the simulation by one env step. action: (action_dim,) in [-1, 1]."""

    @abc.abstractmethod
    def _observe(self, data: mjx.Data, prev_data: mjx.Data | None) -> jax.Array:
        """The observation (obs_dim,) of `data` (prev_data is None right after reset)."""

    @abc.abstractmethod
    def _achieved_goal(self, data: mjx.Data) -> jax.Array:
        """phi(s): (goal_dim,) achieved goal of `data`."""

    @abc.abstractmethod
    def normalize_obs(self, obs: jax.Array) -> jax.Array:
        """Fixed affine map of obs (..., obs_dim) to features of about [-1, 1]."""

    @abc.abstractmethod
    def goal_of_obs(self, obs: jax.Array) -> jax.Array:
        """phi read back from an observation: (..., obs_dim) -> (..., goal_dim).

        Equals `achieved_goal` of the state the observation was made in; the relative goal
        input (`agent_input(..., relative_goal=True)`) uses it.
        """

    # --- the public contract --------------------------------------------------
    @property
    def n_modes(self) -> int:
        """Number of desired outcome modes."""
        return int(self.goal_points.shape[0])

    @property
    def start_goal(self) -> np.ndarray:
        """(goal_dim,) phi of the start state: the centre of the warm-up curriculum (SPEC §5).

        This default resets once (reset noise included) and converts to numpy, so call it
        on the host, never inside a traced function; envs override it with the exact,
        noiseless value.
        """
        state = self.reset_with_goal(jax.random.key(0), np.zeros(self.goal_dim, np.float32))
        return np.asarray(state.achieved_goal)

    def normalize_goal(self, goal: jax.Array) -> jax.Array:
        """Maps goal bounds to [-1, 1]: (..., goal_dim) -> (..., goal_dim)."""
        centre = (self.goal_high + self.goal_low) / 2.0
        half = (self.goal_high - self.goal_low) / 2.0
        return (goal - centre) / half

    def is_success(self, achieved_goal: jax.Array, goal: jax.Array) -> jax.Array:
        """True where ||achieved_goal - goal|| <= success_radius: (..., d) -> (...,)."""
        return goal_distance(achieved_goal, goal) <= self.success_radius

    def reset(self, key: jax.Array) -> EnvState:
        """Resets with a goal drawn uniformly from the mode points."""
        key_mode, key_reset = jax.random.split(key)
        mode = jax.random.randint(key_mode, (), 0, self.n_modes)
        return self.reset_with_goal(key_reset, jnp.asarray(self.goal_points)[mode])

    def reset_with_goal(self, key: jax.Array, goal: jax.Array) -> EnvState:
        """Resets (with reset noise) and conditions the episode on `goal` (goal_dim,)."""
        # The first of two keys: the reset streams of every recorded run stay the same.
        data = self._reset_data(jax.random.split(key)[0])
        achieved = self._achieved_goal(data)
        goal = jnp.asarray(goal, jnp.float32)
        return EnvState(
            data=data,
            obs=self._observe(data, None),
            achieved_goal=achieved,
            goal=goal,
            success=self.is_success(achieved, goal),
        )

    def step(self, state: EnvState, action: jax.Array) -> EnvState:
        """One env step; the goal is kept and `success` recomputed."""
        action = jnp.clip(jnp.asarray(action, jnp.float32), -1.0, 1.0)
        data = self._step_data(state.data, action)
        achieved = self._achieved_goal(data)
        return state.replace(
            data=data,
            obs=self._observe(data, state.data),
            achieved_goal=achieved,
            success=self.is_success(achieved, state.goal),
        )

    def set_goal(self, state: EnvState, goal: jax.Array) -> EnvState:
        """Conditions the episode on a new goal (goal_dim,) and recomputes `success`."""
        goal = jnp.asarray(goal, jnp.float32)
        return state.replace(goal=goal, success=self.is_success(state.achieved_goal, goal))

    def clip_goal(self, goal: jax.Array) -> jax.Array:
        """Projects goals (..., goal_dim) into the valid goal set: clipped to the bounds.

        Envs whose goals live on a sub-manifold (Sawyer push: z = 0.02) override this.
        """
        return jnp.clip(goal, self.goal_low, self.goal_high)

    def sample_uniform_goals(self, key: jax.Array, n: int) -> jax.Array:
        """n points of D_T = U(goal bounds), projected by `clip_goal`: (n, goal_dim)."""
        u = jax.random.uniform(key, (n, self.goal_dim), minval=self.goal_low, maxval=self.goal_high)
        return self.clip_goal(u)


def agent_input(env, obs: jax.Array, goal: jax.Array, relative_goal: bool = False) -> jax.Array:
    """The goal-conditioned input of a policy or value: (..., obs_dim), (..., goal_dim) ->
    (..., feat_dim) float32.

    concat(env.normalize_obs(obs), env.normalize_goal(goal)) (SPEC §4: fixed affine maps,
    no running statistics). `obs` and `goal` broadcast against each other. Our networks
    (`d2c_jax.core.networks.actor_input`) and the brax adapter both use it.

    `relative_goal` (static) replaces the goal feature by the goal's offset from phi(s),
    normalize_goal(g) - normalize_goal(phi(s)) = (g - phi(s)) / half-extent, as HIRO's
    low-level policy sees its goal: the same offset then reads the same wherever the agent
    stands. The width is unchanged and g = phi(s) + offset, so no information is lost.
    """
    obs_feat = env.normalize_obs(obs)
    goal_feat = env.normalize_goal(goal)
    if relative_goal:
        goal_feat = goal_feat - env.normalize_goal(env.goal_of_obs(obs))
    batch = jnp.broadcast_shapes(obs_feat.shape[:-1], goal_feat.shape[:-1])
    obs_feat = jnp.broadcast_to(obs_feat, batch + obs_feat.shape[-1:])
    goal_feat = jnp.broadcast_to(goal_feat, batch + goal_feat.shape[-1:])
    return jnp.concatenate([obs_feat, goal_feat], axis=-1).astype(jnp.float32)


def agent_input_dim(env) -> int:
    """feat_dim of `agent_input` for this env (traced abstractly, no compute)."""
    obs = jax.ShapeDtypeStruct((env.obs_dim,), jnp.float32)
    goal = jax.ShapeDtypeStruct((env.goal_dim,), jnp.float32)
    return jax.eval_shape(lambda o, g: agent_input(env, o, g), obs, goal).shape[-1]


def goal_distance(a: jax.Array, b: jax.Array) -> jax.Array:
    """Euclidean distance over the last axis: (..., d), (..., d) -> (...,)."""
    return jnp.linalg.norm(a - b, axis=-1)


def scan_substeps(step_fn: Callable[[mjx.Data], mjx.Data], data: mjx.Data, n: int) -> mjx.Data:
    """Applies `step_fn` n times with `lax.scan` (physics substeps of one env step)."""

    def body(d, _):
        return step_fn(d), None

    data, _ = jax.lax.scan(body, data, None, length=n)
    return data


def put_mjx(mj_model) -> tuple[mjx.Model, mjx.Data]:
    """The MJX model and a fresh data of `mj_model`, on this process's first device.

    MJX's default is `jax.devices()[0]`, which in a multi-process job belongs to process
    0 only; every other process could not even build its envs there.
    """
    device = jax.local_devices()[0]
    model = mjx.put_model(mj_model, device=device)
    return model, mjx.make_data(model, device=device)
