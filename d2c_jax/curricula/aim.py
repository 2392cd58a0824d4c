"""OUTPACE's temporal-distance potential: an AIM discriminator ensemble (docs/BASELINES.md).

Adversarial Intrinsic Motivation (Durugkar et al. 2021) learns a potential D(x, g) that
estimates the Wasserstein-1 distance, in time steps, from states to a goal: D is pushed
up on target pairs (a point next to the goal, g) and down on the pairs the policy visits
((phi(s'), g)), under a Lipschitz constraint w.r.t. the time-step metric, i.e. D may
change by at most `lipschitz` between consecutive states under the same goal (a
one-sided squared hinge, outpace_official outpacesac.py). So D(x, g) grows towards g and
its steepest ascent follows the agent's own transitions: a distance that knows walls
from experience, not from a map.

The ensemble is `n_members` MLPs (tanh hidden units, as OUTPACE's effectively are, linear
output, orthogonal initialisation); D is their mean.
"""

from __future__ import annotations

import flax.linen as nn
import jax
import jax.numpy as jnp
import optax

from d2c_jax.core import networks
from d2c_jax.curricula.classifier import normalized_pair


class PotentialEnsemble(nn.Module):
    """n members D_k([x, g]) on normalised goal-space pairs: x, g (..., d) -> (n, ...)."""

    n_members: int
    hidden_sizes: tuple[int, ...]
    goal_low: tuple[float, ...]
    goal_high: tuple[float, ...]

    @nn.compact
    def __call__(self, x: jax.Array, g: jax.Array) -> jax.Array:
        h = normalized_pair(x, g, self.goal_low, self.goal_high)
        members = networks.ScalarEnsemble(
            self.n_members, self.hidden_sizes, nn.tanh, nn.initializers.orthogonal()
        )
        return members(h)


def potential(net: PotentialEnsemble, params, x: jax.Array, g: jax.Array) -> jax.Array:
    """D(x, g): the ensemble mean, (...)."""
    return net.apply(params, x, g).mean(axis=0)


def aim_loss(net, params, ag, next_ag, goal, target_x, lipschitz: float, penalty: float):
    """The AIM loss summed over members (each member's own loss; they share the batch).

    Per member: mean D(phi(s'), g) - mean D(x+, g) + penalty * mean(max(|D(phi(s'), g) -
    D(phi(s), g)| - lipschitz, 0)^2), with x+ a point next to g (the target).

    Args:
      ag, next_ag, goal, target_x: (B, d) phi(s), phi(s'), the (relabelled) goal, x+.
    Returns:
      () the summed loss, and the (n, B) values on the target and visited pairs.
    """
    d_next = net.apply(params, next_ag, goal)  # (n, B)
    d_now = net.apply(params, ag, goal)
    d_target = net.apply(params, target_x, goal)
    hinge = jnp.maximum(jnp.abs(d_next - d_now) - lipschitz, 0.0) ** 2
    per_member = d_next.mean(-1) - d_target.mean(-1) + penalty * hinge.mean(-1)
    return per_member.sum(), (d_target, d_now)


def update(net, optimizer, params, opt_state, batch, lipschitz: float, penalty: float):
    """One Adam step of every member; returns (params, opt_state, loss, (2, n, B) values)."""
    (loss, values), grads = jax.value_and_grad(aim_loss, argnums=1, has_aux=True)(
        net, params, *batch, lipschitz, penalty
    )
    updates, opt_state = optimizer.update(grads, opt_state, params)
    return optax.apply_updates(params, updates), opt_state, loss, jnp.stack(values)


def reward_statistics(values: jax.Array, offset: float) -> tuple[jax.Array, jax.Array]:
    """OUTPACE's reward normalisers from the potentials of the last training block:
    (max + offset, std + offset); values (...) -> ((), ())."""
    return values.max() + offset, values.std() + offset


def intrinsic_reward(net, params, next_ag, goal, mean, std) -> jax.Array:
    """r = (D(phi(s'), g) - mean) / (2 std) (OUTPACE's normalised AIM reward), (...)."""
    return (potential(net, params, next_ag, goal) - mean) / (2.0 * std)
