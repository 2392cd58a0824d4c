"""HGG: Hindsight Goal Generation (Ren et al., NeurIPS 2019) as a curriculum of our
interface (`--algo hgg`; docs/BASELINES.md cites every constant).

HGG matches K target goals g_j (draws of the desired examples) to K distinct
trajectories of the pool by the cost (Stilwell-Git/Hindsight-Goal-Generation,
learner/hgg.py, `MatchSampler.update`)

  cost[j, k] = c ||g_k0 - s0_j|| + min_t ( ||g_kt - g_j|| - V(s_k0, g_kt) D (1 - gamma) / L ),

with g_kt the achieved goals of trajectory k, s0_j the start's achieved goal, V the
critic's value of trajectory k's first state conditioned on g_kt, clipped to HGG's
reward scale [-1/(1 - gamma), 0], and D the largest start-to-desired-goal distance. The
argmin state of the matched edge is the goal, without noise (HGG adds noise on its Fetch
tasks only). The learner is our SAC+HER with the sparse reward, not HGG's DDPG.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from d2c_jax import config as config_lib
from d2c_jax.core.types import Metrics
from d2c_jax.curricula import curriculum
from d2c_jax.curricula.interface import Curriculum, CurriculumInputs
from envs import goal_distance


def hgg_value(values: jax.Array, gamma: float) -> jax.Array:
    """Our critic's values (rewards 1/0 for success/not) on HGG's scale (rewards 0/-1):
    V_hgg = V - 1/(1 - gamma), as every step's reward is one less; clipped to
    [-1/(1 - gamma), 0] as HGG clips its own."""
    horizon_value = 1.0 / (1.0 - gamma)
    return jnp.clip(values - horizon_value, -horizon_value, 0.0)


def cost_matrix(
    targets: jax.Array,
    target_start: jax.Array,
    traj: jax.Array,
    traj_start: jax.Array,
    values: jax.Array,
    *,
    diameter: jax.Array | float,
    gamma: float,
    init_distance_weight: float,
    lipschitz: float,
) -> tuple[jax.Array, jax.Array]:
    """HGG's edge costs and their argmin states (module docstring).

    Args:
      targets: (K, d) target goals g_j.
      target_start: (d,) s0_j, the start's achieved goal (one start for every target).
      traj: (P, T, d) candidate achieved goals g_kt of each pool trajectory.
      traj_start: (P, d) g_k0, each trajectory's first achieved goal.
      values: (P, T) our critic's V(s_k0, g_kt), on the 1/0 reward scale.
      diameter: D, the largest start-to-desired-goal distance.
      gamma: the discount.
      init_distance_weight: c.
      lipschitz: L.
    Returns:
      cost (K, P) and candidates (K, P, d), the argmin state of each edge.
    """
    scale = diameter * (1.0 - gamma) / lipschitz
    value_term = hgg_value(values, gamma) * scale  # (P, T)
    dist = goal_distance(traj[None], targets[:, None, None, :])  # (K, P, T)
    residual = dist - value_term[None]
    best = jnp.argmin(residual, axis=-1)  # (K, P)
    start_cost = init_distance_weight * goal_distance(traj_start, target_start)  # (P,)
    cost = jnp.min(residual, axis=-1) + start_cost[None]
    candidates = traj[jnp.arange(traj.shape[0])[None], best]  # (K, P, d)
    return cost, candidates


class HGGCurriculum(Curriculum):
    """HGG's goal generation on D2C's trajectory pool and auction (`--algo hgg`)."""

    reward = config_lib.ALGO_REWARDS["hgg"]
    uses_classifier = False
    needs_pool_obs = True
    needs_value = True

    def propose(self, state, inputs: CurriculumInputs, key) -> tuple[jax.Array, Metrics, object]:
        """K goals by HGG's matching; before the pool is full, D2C's warm-up goals."""
        cur, env = self.cfg.curriculum, self.env
        key_slots, key_warm = jax.random.split(key)
        targets = curriculum.goal_slots(env, cur.n_slots, key_slots)  # (K, d)
        # Every cost_stride-th state plus the final one, over the whole trajectory (HGG
        # scores every state; the stride bounds the critic calls, docs/BASELINES.md).
        traj = curriculum.subsample(inputs.pool_ag, cur.cost_stride)  # (P, T', d)
        first_obs = inputs.pool_obs[:, :1]  # (P, 1, o): V of each trajectory's first state
        obs_shape = traj.shape[:2] + first_obs.shape[-1:]
        values = inputs.value_fn(jnp.broadcast_to(first_obs, obs_shape), traj)  # (P, T')
        cost, candidates = cost_matrix(
            targets, inputs.start_goal, traj, inputs.pool_ag[:, 0], values,
            diameter=curriculum.start_to_desired_distance(env, inputs.start_goal),
            gamma=self.cfg.sac.gamma,
            init_distance_weight=self.cfg.hgg.init_distance_weight,
            lipschitz=self.cfg.hgg.lipschitz,
        )  # fmt: skip
        no_noise = jnp.zeros_like(targets)  # HGG adds noise on its Fetch tasks only
        goals, matched_cost, full, converged = curriculum.assign_goals(
            cur, env, cost, candidates, inputs.pool_ag, inputs.pool_valid, inputs.start_goal,
            no_noise, key_warm,
        )  # fmt: skip
        metrics = curriculum.proposal_metrics(goals, targets, matched_cost, full, converged)
        return goals, metrics, state
