"""Goal-conditioned soft actor-critic: losses and one fused update (SPEC §4).

Equations cite Haarnoja et al. 2018, "Soft Actor-Critic Algorithms and Applications"
(arXiv 1812.05905): the soft state value (Eq. 3), the critic objective J_Q (Eq. 5) with
clipped double-Q, the reparameterised policy objective J_pi (Eq. 7) and the temperature
objective J(alpha) (Eq. 18); the tanh log-density is Eq. 21 of arXiv 1801.01290.

Schedule (paper Table 2): the critic is updated every update; the actor and log alpha
every `actor_update_every` updates; the target critic by Polyak averaging every
`target_update_every` updates. `update_sac_block` runs `block_size(cfg)` consecutive
updates unrolled statically (e.g. critic; critic + actor + target), so no `lax.cond` on
the update counter is needed: under `jax.vmap` over seeds a cond would become a select
and compute the actor update on every update (up to ~1.5x slower).

Hyperparameters that keep shapes (learning rates, tau, the initial alpha) are a pytree,
`SACHyperparams`, that the update reads as traced values rather than constants baked into
the compiled program, so a sweep can vmap over them; the static `Optimizers` are Adam
with a traced step size (`optim`).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import optax
from flax import struct

from d2c_jax.config import SACConfig
from d2c_jax.core import networks, optim, types
from d2c_jax.core.types import Batch, Metrics


@struct.dataclass
class SACState:
    """Parameters and optimiser states of SAC (leading seed axis when vmapped)."""

    actor_params: dict  # actor MLP weights
    critic_params: dict  # twin critic, leaves (2, ...)
    target_critic_params: dict  # Polyak-averaged copy of critic_params, leaves (2, ...)
    log_alpha: jax.Array  # () float32 log of the entropy temperature
    actor_opt: optax.OptState  # Adam state of the actor
    critic_opt: optax.OptState  # Adam state of the critic
    alpha_opt: optax.OptState  # Adam state of log alpha
    step: jax.Array  # () int32 updates done
    actor_loss: jax.Array  # () float32 latest actor loss (logged on critic-only updates)


@struct.dataclass
class SACHyperparams:
    """SAC's shape-keeping hyperparameters as traced values (leading seed axis when vmapped)."""

    actor_lr: jax.Array  # () float32 Adam step size of the actor (Table 2: 1e-4)
    critic_lr: jax.Array  # () float32 Adam step size of the critic
    alpha_lr: jax.Array  # () float32 Adam step size of log alpha
    tau: jax.Array  # () float32 Polyak rate of the target critic
    init_log_alpha: jax.Array  # () float32 log of the initial temperature (used by init)


def hyperparams(cfg: SACConfig) -> SACHyperparams:
    """The config's values; log alpha is taken on the host, in double precision."""
    return types.float32_scalars(SACHyperparams, cfg, init_log_alpha=math.log(cfg.init_alpha))


class Optimizers(NamedTuple):
    """The three optimisers (static; their states live in SACState): `optim.adam`, whose
    step size `optim.adam_step` takes from `SACHyperparams`."""

    actor: optax.GradientTransformation
    critic: optax.GradientTransformation
    alpha: optax.GradientTransformation


def make_optimizers() -> Optimizers:
    """Adam for the actor, the critic and log alpha (Table 2), step sizes traced."""
    return Optimizers(optim.adam(), optim.adam(), optim.adam())


def target_entropy(cfg: SACConfig, action_dim: int) -> float:
    """cfg.target_entropy, or -|A| by default."""
    return -float(action_dim) if cfg.target_entropy is None else float(cfg.target_entropy)


def block_size(cfg: SACConfig) -> int:
    """Updates per `update_sac_block`: lcm of the actor and target cadences."""
    return math.lcm(cfg.actor_update_every, cfg.target_update_every)


def init_sac(
    nets: networks.SACNetworks, opt: Optimizers, env, hp: SACHyperparams, key: jax.Array
) -> SACState:
    """Fresh parameters: target critic = critic, log alpha = hp.init_log_alpha."""
    key_actor, key_critic = jax.random.split(key)
    feats = jnp.zeros((1, networks.feature_dim(env)), jnp.float32)
    actor_params = nets.actor.init(key_actor, feats)
    critic_params = nets.critic.init(key_critic, feats, jnp.zeros((1, env.action_dim)))
    log_alpha = jnp.asarray(hp.init_log_alpha, jnp.float32)
    return SACState(
        actor_params=actor_params,
        critic_params=critic_params,
        # A copy, not an alias: callers may donate the state to a jitted step.
        target_critic_params=jax.tree.map(jnp.copy, critic_params),
        log_alpha=log_alpha,
        actor_opt=opt.actor.init(actor_params),
        critic_opt=opt.critic.init(critic_params),
        alpha_opt=opt.alpha.init(log_alpha),
        step=jnp.zeros((), jnp.int32),
        actor_loss=jnp.zeros((), jnp.float32),
    )


# --- losses -----------------------------------------------------------------------------


def soft_td_target(
    nets: networks.SACNetworks,
    actor_params,
    target_critic_params,
    alpha: jax.Array,
    next_feats: jax.Array,
    reward: jax.Array,
    mask: jax.Array,
    gamma: float,
    key: jax.Array,
) -> tuple[jax.Array, jax.Array]:
    """y = r + gamma * mask * V(s'), V(s') = min_i Qbar_i(s', a') - alpha log pi(a'|s') (Eq. 3).

    Args:
      next_feats: (B, feat_dim) features of (s', g); reward, mask: (B,).
    Returns:
      y (B,) without gradient, and log pi(a'|s') (B,) (a free entropy estimate).
    """
    mean, log_std = nets.actor.apply(actor_params, next_feats)
    next_action, next_log_prob = networks.squashed_gaussian_sample(mean, log_std, key)
    q_next = nets.critic.apply(target_critic_params, next_feats, next_action)  # (2, B)
    v_next = jnp.min(q_next, axis=0) - alpha * next_log_prob
    return jax.lax.stop_gradient(reward + gamma * mask * v_next), next_log_prob


def soft_return_floor(alpha, target_entropy: float, gamma: float):
    """The soft return of a policy that earns no reward and keeps its entropy at
    `target_entropy` H* for ever: Q = gamma (Q + alpha H*) (Eq. 3 with r = 0), so
    Q = gamma alpha H* / (1 - gamma). With rewards in [0, 1] no soft Q-value of a policy at
    its entropy target lies below it."""
    return gamma * alpha * target_entropy / (1.0 - gamma)


def clip_to_return_range(y: jax.Array, gamma: float) -> jax.Array:
    """y clipped to [0, 1 / (1 - gamma)], the discounted return's range for rewards in
    [0, 1] (p_pseudo and the sparse ablation): a critic that overshoots it (measured on
    Ant at one update per env step: Q 362 against the bound 100) cannot feed that back
    into its own targets."""
    return jnp.clip(y, 0.0, 1.0 / (1.0 - gamma))


def critic_loss(
    critic_params, nets: networks.SACNetworks, feats: jax.Array, action: jax.Array, y: jax.Array
) -> tuple[jax.Array, jax.Array]:
    """J_Q (Eq. 5) summed over the twin critics: 0.5 * sum_i mean_B (Q_i(s, a) - y)^2.

    Args:
      feats: (B, feat_dim); action: (B, action_dim); y: (B,) soft TD target.
    Returns:
      loss () and q (2, B).
    """
    q = nets.critic.apply(critic_params, feats, action)  # (2, B)
    loss = 0.5 * jnp.sum(jnp.mean((q - y[None]) ** 2, axis=-1))
    return loss, q


def actor_loss(
    actor_params,
    nets: networks.SACNetworks,
    critic_params,
    alpha: jax.Array,
    feats: jax.Array,
    key: jax.Array,
    mean_reg: float = 0.0,
) -> tuple[jax.Array, jax.Array]:
    """J_pi (Eq. 7, reparameterised): mean_B [alpha log pi(a~|s) - min_i Q_i(s, a~)], plus
    mean_B mean_reg * ||u||^2 on the pre-tanh mean u (B, |A|) when mean_reg > 0
    (`SACConfig.actor_mean_reg`).

    Returns:
      loss () and log pi(a~|s) (B,).
    """
    mean, log_std = nets.actor.apply(actor_params, feats)
    action, log_prob = networks.squashed_gaussian_sample(mean, log_std, key)
    q = jnp.min(nets.critic.apply(critic_params, feats, action), axis=0)  # (B,)
    loss = alpha * log_prob - q
    if mean_reg > 0:  # static: the default program is unchanged
        # Where tanh saturates, dQ/du and the noise's effect on the action vanish, so
        # nothing in J_pi pulls u back; this term does (measured on the Ant's frozen
        # goals: |u| up to 12, docs/DEVIATIONS.md).
        loss = loss + mean_reg * jnp.sum(jnp.square(mean), axis=-1)
    return jnp.mean(loss), log_prob


def alpha_loss(log_alpha: jax.Array, log_prob: jax.Array, entropy_target: float) -> jax.Array:
    """J(alpha) (Eq. 18) in log alpha: -mean_B log_alpha * (log pi(a|s) + target_entropy)."""
    return -jnp.mean(log_alpha * jax.lax.stop_gradient(log_prob + entropy_target))


# --- the update -------------------------------------------------------------------------


def _critic_step(cfg: SACConfig, nets, opt, hp, state: SACState, feats, next_feats, batch, key):
    """Soft TD target, then one Adam step on J_Q."""
    alpha = jnp.exp(state.log_alpha)
    y, next_log_prob = soft_td_target(
        nets, state.actor_params, state.target_critic_params, alpha, next_feats,
        batch.reward, batch.mask, cfg.gamma, key,
    )  # fmt: skip
    # Share of targets below what any behaviour can earn (SPEC §4's sanity bound); read
    # before the clip, so with `clip_target` it is the share the clip lifts.
    floor = soft_return_floor(alpha, target_entropy(cfg, batch.action.shape[-1]), cfg.gamma)
    below_floor = jnp.mean(y < floor)
    if cfg.clip_target:
        y = clip_to_return_range(y, cfg.gamma)
    grad_fn = jax.value_and_grad(critic_loss, has_aux=True)
    (loss, q), grads = grad_fn(state.critic_params, nets, feats, batch.action, y)
    params, opt_state = optim.adam_step(
        opt.critic, hp.critic_lr, grads, state.critic_opt, state.critic_params
    )
    metrics = {
        "sac/critic_loss": loss,
        "sac/q_mean": jnp.mean(q),
        "sac/target_mean": jnp.mean(y),
        "sac/target_below_floor": below_floor,
        "sac/entropy": -jnp.mean(next_log_prob),
        "sac/reward_mean": jnp.mean(batch.reward),
    }
    return state.replace(critic_params=params, critic_opt=opt_state), metrics


def _actor_step(cfg: SACConfig, nets, opt, hp, state: SACState, feats, action_dim: int, key):
    """One Adam step on J_pi (with the just-updated critic), then one on J(alpha)."""
    alpha = jnp.exp(state.log_alpha)
    grad_fn = jax.value_and_grad(actor_loss, has_aux=True)
    (loss, log_prob), grads = grad_fn(
        state.actor_params, nets, state.critic_params, alpha, feats, key, cfg.actor_mean_reg
    )
    actor_params, actor_opt = optim.adam_step(
        opt.actor, hp.actor_lr, grads, state.actor_opt, state.actor_params
    )
    state = state.replace(actor_params=actor_params, actor_opt=actor_opt, actor_loss=loss)
    if not cfg.learn_alpha:
        return state
    # The alpha step reuses log pi(a~|s) of the actor step (pre-update actor).
    a_grads = jax.grad(alpha_loss)(state.log_alpha, log_prob, target_entropy(cfg, action_dim))
    log_alpha, alpha_opt = optim.adam_step(
        opt.alpha, hp.alpha_lr, a_grads, state.alpha_opt, state.log_alpha
    )
    return state.replace(log_alpha=log_alpha, alpha_opt=alpha_opt)


def _polyak(state: SACState, tau: jax.Array | float) -> SACState:
    """Target <- (1 - tau) target + tau critic."""
    target = jax.tree.map(
        lambda t, p: t + tau * (p - t), state.target_critic_params, state.critic_params
    )
    return state.replace(target_critic_params=target)


def _features(nets: networks.SACNetworks, env, batch: Batch) -> tuple[jax.Array, jax.Array]:
    """(B, feat_dim) features of (s, g) and (s', g), computed once per update."""
    feats = networks.actor_input(env, batch.obs, batch.goal, nets.relative_goal)
    next_feats = networks.actor_input(env, batch.next_obs, batch.goal, nets.relative_goal)
    return feats, next_feats


def _finish(state: SACState, metrics: Metrics) -> tuple[SACState, Metrics]:
    """Counts the update and adds the actor loss and alpha to its metrics."""
    metrics = {**metrics, "sac/actor_loss": state.actor_loss, "sac/alpha": jnp.exp(state.log_alpha)}
    return state.replace(step=state.step + 1), metrics


def update_sac_block(
    cfg: SACConfig,
    nets: networks.SACNetworks,
    opt: Optimizers,
    hp: SACHyperparams,
    state: SACState,
    batches: Batch,
    env,
    key: jax.Array,
) -> tuple[SACState, Metrics]:
    """`block_size(cfg)` SAC updates, statically unrolled: no cond, cheap under vmap.

    Update i (1-based within the block) steps the critic; the actor and alpha when i is a
    multiple of `actor_update_every`; the target when i is one of `target_update_every`.
    Blocks keep state.step a multiple of block_size, so these are the global cadences.

    Args:
      cfg: SAC config (static); nets, opt: the modules and optimisers; hp: the traced
        hyperparameters.
      state: SAC state.
      batches: a Batch whose leaves have a leading axis block_size(cfg), then B (raw obs
        and goals).
      env: the env (its normalize_obs / normalize_goal build the features).
      key: PRNG key, split into one key per update.
    Returns:
      The new state and the flat "sac/*" metrics averaged over the block.
    """
    n = block_size(cfg)
    keys = jax.random.split(key, n)
    all_metrics = []
    for i in range(n):
        batch = jax.tree.map(lambda x, i=i: x[i], batches)
        key_critic, key_actor = jax.random.split(keys[i])
        feats, next_feats = _features(nets, env, batch)
        state, metrics = _critic_step(
            cfg, nets, opt, hp, state, feats, next_feats, batch, key_critic
        )
        if (i + 1) % cfg.actor_update_every == 0:
            state = _actor_step(cfg, nets, opt, hp, state, feats, env.action_dim, key_actor)
        if (i + 1) % cfg.target_update_every == 0:
            state = _polyak(state, hp.tau)
        state, metrics = _finish(state, metrics)
        all_metrics.append(metrics)
    return state, jax.tree.map(lambda *xs: jnp.mean(jnp.stack(xs)), *all_metrics)


# --- acting -----------------------------------------------------------------------------


def make_policy(nets: networks.SACNetworks, state: SACState, env, deterministic: bool = False):
    """policy(obs (obs_dim,), goal (goal_dim,), key) -> action (action_dim,), for rollouts.

    `deterministic` gives tanh(mean) (evaluation, SPEC §7); otherwise a sample.
    """

    def policy(obs: jax.Array, goal: jax.Array, key: jax.Array) -> jax.Array:
        feats = networks.actor_input(env, obs, goal, nets.relative_goal)
        return networks.select_action(nets, state.actor_params, feats, key, deterministic)

    return policy


def state_value(
    nets: networks.SACNetworks, state: SACState, env, obs: jax.Array, goals: jax.Array
) -> jax.Array:
    """V(s, g) = min_i Q_i(s, pi(s, g), g) with the deterministic action tanh(mean).

    Used by the "+Value" curriculum ablation (appendix C.2).

    Args:
      obs: (..., obs_dim), broadcast against goals (e.g. one start obs (obs_dim,)).
      goals: (..., goal_dim).
    Returns:
      (...,) values.
    """
    feats = networks.actor_input(env, obs, goals, nets.relative_goal)
    action = networks.select_action(nets, state.actor_params, feats, None, deterministic=True)
    return jnp.min(nets.critic.apply(state.critic_params, feats, action), axis=0)
