"""VDS: Value Disagreement Sampling (Zhang et al. 2020) as a teacher (`--algo vds`, issue 20).

An ensemble of Q-functions, each trained by its own TD regression on the replay buffer
with the sparse reward, disagrees most about goals at the edge of what the agent can
do. Each iteration the teacher draws candidate goals uniformly over the goal bounds,
scores each by the ensemble's standard deviation of Q(s0, a, g) at the start state
(a ~ pi(s0, g)) and samples goals in proportion to it (psclklnk/currot
deep_sprl/teachers/vds/vds.py; docs/BASELINES.md).
"""

from __future__ import annotations

import flax.linen as nn
import jax
import jax.numpy as jnp
import optax
from flax import struct

from d2c_jax.core import her, networks, replay
from d2c_jax.curricula import teachers
from d2c_jax.curricula.interface import CurriculumInputs


class QEnsemble(nn.Module):
    """n members Q_k(features, action): (..., f), (..., a) -> (n, ...), tanh MLPs."""

    n_members: int
    hidden_sizes: tuple[int, ...]

    @nn.compact
    def __call__(self, features: jax.Array, action: jax.Array) -> jax.Array:
        members = networks.ScalarEnsemble(self.n_members, self.hidden_sizes, nn.tanh)
        return members(jnp.concatenate([features, action], axis=-1))


@struct.dataclass
class VDSState:
    """The Q ensemble and its optimiser."""

    params: dict  # QEnsemble parameters (leading member axis inside)
    opt: optax.OptState  # Adam state


def td_loss(net, params, feats, action, reward, next_feats, next_action, gamma) -> jax.Array:
    """sum over members of mean (Q_k(s, a) - (r + gamma Q_k(s', a')))^2, the target from
    the same ensemble without gradient (VDS has no target network). Shapes (B, ...)."""
    q = net.apply(params, feats, action)  # (n, B)
    target = reward + gamma * jax.lax.stop_gradient(net.apply(params, next_feats, next_action))
    return jnp.mean((q - target) ** 2, axis=-1).sum()


def disagreement(net, params, feats: jax.Array, action: jax.Array) -> jax.Array:
    """The members' population std of Q at (features, action): (C, f), (C, a) -> (C,)."""
    return jnp.std(net.apply(params, feats, action), axis=0)


def sample_by_disagreement(std: jax.Array, n: int, key) -> jax.Array:
    """n indices drawn with p_i = std_i / sum std (vds.py:72-85), uniform when every std
    is 0 (a fresh ensemble): (C,) -> (n,) int32."""
    logits = jnp.where(std.sum() > 0, jnp.log(std), 0.0)
    return jax.random.categorical(key, logits, shape=(n,))


class VDSTeacher(teachers.Teacher):
    """Goals sampled in proportion to the Q ensemble's disagreement at the start state."""

    needs_start_obs = True

    def __init__(self, cfg, env, classifier_net, uses_goal_value: bool = False):
        super().__init__(cfg, env, classifier_net, uses_goal_value)
        t = cfg.teachers
        self.net = QEnsemble(t.vds_members, t.vds_hidden_sizes)
        self.optimizer = optax.adam(t.vds_lr)
        steps = cfg.num_envs * env.horizon  # env steps per iteration
        self.updates = max(1, round(t.vds_updates_per_10k * steps / 10_000))

    def init(self, key) -> VDSState:
        feat_dim = networks.actor_input(
            self.env, jnp.zeros(self.env.obs_dim), jnp.zeros(self.env.goal_dim)
        ).shape[-1]
        params = self.net.init(key, jnp.zeros((1, feat_dim)), jnp.zeros((1, self.env.action_dim)))
        return VDSState(params=params, opt=self.optimizer.init(params))

    def propose(self, state: VDSState, inputs: CurriculumInputs, key):
        k_cand, k_act, k_pick, k_metrics = jax.random.split(key, 4)
        t, k = self.cfg.teachers, self.cfg.curriculum.n_slots
        cands = self.env.sample_uniform_goals(k_cand, t.vds_candidates)  # (C, d)
        start = jnp.broadcast_to(inputs.start_obs, (cands.shape[0],) + inputs.start_obs.shape)
        action = inputs.policy(start, cands, k_act)
        feats = networks.actor_input(self.env, start, cands)
        std = disagreement(self.net, state.params, feats, action)
        goals = cands[sample_by_disagreement(std, k, k_pick)]
        return goals, self.metrics(goals, k_metrics), state

    def observe(self, state: VDSState, episodes, inputs: CurriculumInputs):
        del episodes
        t, gamma = self.cfg.teachers, self.cfg.sac.gamma
        reward_fn = her.sparse_reward_fn(self.env)

        def one(carry, key):
            params, opt = carry
            k_batch, k_act = jax.random.split(key)
            tr = replay.sample(inputs.replay, t.vds_batch_size, k_batch)
            next_action = inputs.policy(tr.next_obs, tr.goal, k_act)
            feats = networks.actor_input(self.env, tr.obs, tr.goal)
            next_feats = networks.actor_input(self.env, tr.next_obs, tr.goal)
            reward = reward_fn(tr.next_achieved_goal, tr.goal)
            loss, grads = jax.value_and_grad(td_loss, argnums=1)(
                self.net, params, feats, tr.action, reward, next_feats, next_action, gamma
            )
            updates, opt = self.optimizer.update(grads, opt, params)
            return (optax.apply_updates(params, updates), opt), loss

        keys = jax.random.split(inputs.key, self.updates)
        (params, opt), losses = jax.lax.scan(one, (state.params, state.opt), keys)
        return VDSState(params=params, opt=opt), {"vds/td_loss": losses.mean()}
