"""Actor and twin critic of goal-conditioned SAC (SPEC §4, Haarnoja et al. 2018).

Both networks take already-normalised features `actor_input(env, obs, goal)` =
concat(env.normalize_obs(obs), env.normalize_goal(goal)); the critic also takes the
action. The twin critic is one flax module whose parameters are a stacked pytree with
leading axis 2 (`nn.vmap`), so both Q-heads run as one batched matmul.

The actor is a tanh-squashed Gaussian. Two details keep it numerically healthy (SPEC §4):
  * the log-std is squashed smoothly into [log_std_min, log_std_max] with a tanh, so it
    keeps a gradient everywhere (a hard clip has none outside its range, and a collapsed
    policy could then never regain entropy);
  * the tanh change of variables uses log(1 - tanh(u)^2) = 2 (log 2 - u - softplus(-2u)),
    exact and finite for every u (the naive log(1 - a^2 + 1e-6) has no gradient once
    float32 tanh saturates).
"""

from __future__ import annotations

import math
from typing import Callable, NamedTuple

import flax.linen as nn
import jax
import jax.numpy as jnp

from d2c_jax.config import SACConfig
from envs import base as env_base

N_CRITICS = 2
"""Members of the twin critic (clipped double-Q)."""


class MLP(nn.Module):
    """MLP with a linear output layer: ReLU hidden units and flax's default (LeCun
    normal) weights unless `activation` and `kernel_init` say otherwise; with
    `layer_norm`, each hidden layer is Dense -> LayerNorm -> activation."""

    hidden_sizes: tuple[int, ...]
    out_dim: int
    activation: Callable[[jax.Array], jax.Array] = nn.relu
    kernel_init: Callable = nn.initializers.lecun_normal()
    layer_norm: bool = False

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        for width in self.hidden_sizes:
            x = nn.Dense(width, kernel_init=self.kernel_init)(x)
            if self.layer_norm:
                x = nn.LayerNorm()(x)
            x = self.activation(x)
        return nn.Dense(self.out_dim, kernel_init=self.kernel_init)(x)


class ScalarEnsemble(nn.Module):
    """`n_members` independent scalar MLPs with stacked parameters (leading axis n), run
    as one batched matmul: x (..., f) -> (n_members, ...). The curricula's ensembles
    (OUTPACE's AIM potential, VDS's Q-functions) are this."""

    n_members: int
    hidden_sizes: tuple[int, ...]
    activation: Callable[[jax.Array], jax.Array] = nn.relu
    kernel_init: Callable = nn.initializers.lecun_normal()

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        stacked = nn.vmap(
            MLP,
            variable_axes={"params": 0},
            split_rngs={"params": True},
            in_axes=None,
            axis_size=self.n_members,
        )
        mlp = stacked(self.hidden_sizes, 1, self.activation, self.kernel_init, name="members")
        return mlp(x)[..., 0]


class Actor(nn.Module):
    """Gaussian policy head before the tanh squashing.

    Returns:
      mean (..., action_dim) and log_std (..., action_dim) in [log_std_min, log_std_max].
    """

    action_dim: int
    hidden_sizes: tuple[int, ...]
    log_std_min: float = -10.0
    log_std_max: float = 2.0

    @nn.compact
    def __call__(self, features: jax.Array) -> tuple[jax.Array, jax.Array]:
        out = MLP(self.hidden_sizes, 2 * self.action_dim)(features)
        mean, raw = jnp.split(out, 2, axis=-1)
        # SPEC §4: log sigma = lo + (hi - lo)/2 (tanh(x) + 1), smooth, never a hard clip.
        half_range = 0.5 * (self.log_std_max - self.log_std_min)
        log_std = self.log_std_min + half_range * (jnp.tanh(raw) + 1.0)
        return mean, log_std


class QNetwork(nn.Module):
    """One critic Q(s, a, g): (..., feat_dim), (..., action_dim) -> (...,).

    With `output_bound` = b, the output is b * sigmoid(raw) in (0, b): the critic cannot
    extrapolate outside the return's range (`SACConfig.bounded_critic`).
    """

    hidden_sizes: tuple[int, ...]
    layer_norm: bool = False
    output_bound: float | None = None

    @nn.compact
    def __call__(self, features: jax.Array, action: jax.Array) -> jax.Array:
        x = jnp.concatenate([features, action], axis=-1)
        raw = MLP(self.hidden_sizes, 1, layer_norm=self.layer_norm)(x)[..., 0]
        if self.output_bound is None:
            return raw
        return self.output_bound * jax.nn.sigmoid(raw)


class TwinCritic(nn.Module):
    """`N_CRITICS` independent critics with stacked parameters (leading axis N_CRITICS).

    Returns:
      q (N_CRITICS, ...) for features (..., feat_dim) and action (..., action_dim).
    """

    hidden_sizes: tuple[int, ...]
    layer_norm: bool = False
    output_bound: float | None = None

    @nn.compact
    def __call__(self, features: jax.Array, action: jax.Array) -> jax.Array:
        stacked = nn.vmap(
            QNetwork,
            variable_axes={"params": 0},
            split_rngs={"params": True},
            in_axes=None,
            out_axes=0,
            axis_size=N_CRITICS,
        )
        members = stacked(self.hidden_sizes, self.layer_norm, self.output_bound, name="members")
        return members(features, action)


class SACNetworks(NamedTuple):
    """The static flax modules of SAC (no parameters: those live in `SACState`)."""

    actor: Actor
    critic: TwinCritic
    relative_goal: bool = False
    """Both networks see the goal as its offset from phi(s) (`SACConfig.relative_goal`)."""


def make_networks(cfg: SACConfig, env) -> SACNetworks:
    """Actor and twin critic sized by `cfg.hidden_sizes` and `env.action_dim`."""
    actor = Actor(
        action_dim=env.action_dim,
        hidden_sizes=tuple(cfg.hidden_sizes),
        log_std_min=cfg.log_std_min,
        log_std_max=cfg.log_std_max,
    )
    # The return's range [0, 1/(1 - gamma)] of rewards in [0, 1] (SPEC §4's sanity bound).
    bound = 1.0 / (1.0 - cfg.gamma) if cfg.bounded_critic else None
    critic = TwinCritic(
        hidden_sizes=tuple(cfg.hidden_sizes), layer_norm=cfg.critic_layer_norm, output_bound=bound
    )
    return SACNetworks(actor=actor, critic=critic, relative_goal=cfg.relative_goal)


# --- features ---------------------------------------------------------------------------


def actor_input(env, obs: jax.Array, goal: jax.Array, relative_goal: bool = False) -> jax.Array:
    """Network features: (..., obs_dim), (..., goal_dim) -> (..., feat_dim).

    concat(env.normalize_obs(obs), env.normalize_goal(goal)) (SPEC §4), defined once in
    `envs.base.agent_input`, which the brax adapter shares; `relative_goal` (static) gives
    the goal as its offset from phi(s) instead (same width).
    """
    return env_base.agent_input(env, obs, goal, relative_goal)


def feature_dim(env) -> int:
    """Width of `actor_input` for this env (traced abstractly, no compute)."""
    return env_base.agent_input_dim(env)


# --- the squashed Gaussian --------------------------------------------------------------


def log1m_tanh_sq(u: jax.Array) -> jax.Array:
    """log(1 - tanh(u)^2) = 2 (log 2 - u - softplus(-2u)), exact and stable for all u."""
    return 2.0 * (math.log(2.0) - u - jax.nn.softplus(-2.0 * u))


def squashed_gaussian_sample(
    mean: jax.Array, log_std: jax.Array, key: jax.Array
) -> tuple[jax.Array, jax.Array]:
    """Reparameterised tanh-Gaussian sample and its log-density (Haarnoja 2018, App. C).

    a = tanh(u), u = mean + std * eps;
    log pi(a|s) = sum_i [log N(u_i; mean_i, std_i) - log(1 - tanh(u_i)^2)]  (Eq. 21).

    Args:
      mean, log_std: (..., action_dim).
      key: PRNG key.
    Returns:
      action (..., action_dim) in (-1, 1) and log_prob (...,).
    """
    eps = jax.random.normal(key, mean.shape, mean.dtype)
    u = mean + jnp.exp(log_std) * eps
    gauss = -0.5 * eps**2 - log_std - 0.5 * math.log(2.0 * math.pi)
    log_prob = jnp.sum(gauss - log1m_tanh_sq(u), axis=-1)
    return jnp.tanh(u), log_prob


def select_action(
    nets: SACNetworks,
    actor_params,
    features: jax.Array,
    key: jax.Array,
    deterministic: bool = False,
) -> jax.Array:
    """Action for features (..., feat_dim) -> (..., action_dim) in (-1, 1).

    `deterministic` (static) gives tanh(mean), the evaluation action of SPEC §7.
    """
    mean, log_std = nets.actor.apply(actor_params, features)
    if deterministic:
        return jnp.tanh(mean)
    action, _ = squashed_gaussian_sample(mean, log_std, key)
    return action
