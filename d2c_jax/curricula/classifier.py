"""The diversified conditional classifier ensemble of D2C (SPEC §3, paper Eq. 5).

One network with a shared trunk and N heads (DivDis style): head i gives
f_i(x; g) = "is x a desired outcome, given the conditioning goal g". Trained with
  - BCE(f_i(phi(s); g), 0) on states from the replay buffer,
  - BCE(f_i(g + eps; g), 1) on noisy conditioning goals,
  - lambda * mean_{i<j} MI(f_i, f_j) on uniform points of the goal bounds,
  - optionally lambda * mu * sum_i KL(mean f_i || prior) on the same points (DivDis),
where all terms share the conditioning goals g ~ D_G. The intent (D2C §4.2-4.4): the
heads agree where there is data and disagree elsewhere, so p_pseudo = mean_i f_i is ~0
on visited states, ~1 at the desired outcomes and ~0.5 in unexplored space. With D_G
uniform, Eq. 5 alone gets the first two but leaves p_pseudo ~0 in unexplored space;
the marginal term gets the third (`marginal_kl`).
"""

from __future__ import annotations

import itertools
from typing import NamedTuple

import flax.linen as nn
import jax
import jax.numpy as jnp
import optax
from flax import struct

from d2c_jax.config import ClassifierConfig
from d2c_jax.core import optim, types
from d2c_jax.core.types import Metrics, RewardFn
from envs import GoalEnv

_P_CLIP = 1e-6  # SPEC §3: probabilities clipped to [1e-6, 1 - 1e-6] in the MI estimator


class Classifier(nn.Module):
    """Shared ReLU trunk with `n_heads` linear heads; raw goal-space inputs.

    Inputs are normalised inside with the goal bounds, (x - centre) / half-extent, so
    callers pass raw achieved goals and goals (SPEC §3).

    Attributes:
      n_heads: number of heads N.
      hidden_sizes: widths of the shared trunk.
      goal_low: (goal_dim,) lower goal bounds, as a tuple (hashable module field).
      goal_high: (goal_dim,) upper goal bounds, as a tuple.
    """

    n_heads: int
    hidden_sizes: tuple[int, ...]
    goal_low: tuple[float, ...]
    goal_high: tuple[float, ...]

    @nn.compact
    def __call__(self, x: jax.Array, g: jax.Array) -> jax.Array:
        """Logits of every head: x (..., d), g (..., d) (broadcast) -> (..., n_heads)."""
        h = normalized_pair(x, g, self.goal_low, self.goal_high)
        for width in self.hidden_sizes:
            h = nn.relu(nn.Dense(width)(h))
        return nn.Dense(self.n_heads)(h)


def normalized_pair(x, g, goal_low, goal_high) -> jax.Array:
    """concat((x - centre) / half, (g - centre) / half) with the goal bounds' centre and
    half-extent: x, g (..., d) (broadcast) -> (..., 2d) float32 (SPEC §3's normalisation)."""
    low = jnp.asarray(goal_low, jnp.float32)
    high = jnp.asarray(goal_high, jnp.float32)
    centre, half = (high + low) / 2.0, (high - low) / 2.0
    x, g = jnp.broadcast_arrays(jnp.asarray(x, jnp.float32), jnp.asarray(g, jnp.float32))
    return jnp.concatenate([(x - centre) / half, (g - centre) / half], axis=-1)


@struct.dataclass
class ClassifierState:
    """Parameters and optimiser state of the classifier."""

    params: dict  # flax params of `Classifier` (trunk and heads)
    opt_state: optax.OptState  # Adam state


@struct.dataclass
class ClassifierHyperparams:
    """The classifier's shape-keeping hyperparameters as traced values (leading seed axis
    when vmapped), so that a sweep can vmap over them."""

    lr: jax.Array  # () float32 Adam step size (Table 2: 1e-3)
    diversity_weight: jax.Array  # () float32 lambda of Eq. 5 (Table 3)
    marginal_weight: jax.Array  # () float32 mu of the marginal term (DEVIATIONS.md)
    marginal_prior: jax.Array  # () float32 the marginal term's Bernoulli prior, in (0, 1)
    eps: jax.Array  # () float32 half-width c of the positives' noise (Table 3 eps)


def hyperparams(cfg: ClassifierConfig) -> ClassifierHyperparams:
    """The config's values as float32 scalars."""
    return types.float32_scalars(ClassifierHyperparams, cfg)


class ClassifierBatch(NamedTuple):
    """One batch of Eq. 5; row b of every term shares the conditioning goal cond_goals[b]."""

    negatives: jax.Array  # (B, goal_dim) achieved goals phi(s) of buffer states, label 0
    positives: jax.Array  # (B, goal_dim) cond_goals + eps noise, label 1
    uniform: jax.Array  # (B, goal_dim) unlabelled points u ~ D_T, for the MI term
    cond_goals: jax.Array  # (B, goal_dim) conditioning goals g ~ D_G
    uniform_goals: jax.Array  # (B, goal_dim) the goal each u is paired with: cond_goals, or
    # groups of `marginal_group` consecutive rows sharing one of them (per-goal marginal)


def make_classifier(cfg: ClassifierConfig, env: GoalEnv) -> Classifier:
    """The classifier module for `env`'s goal bounds."""
    return Classifier(
        n_heads=cfg.n_heads,
        hidden_sizes=tuple(cfg.hidden_sizes),
        goal_low=tuple(float(v) for v in env.goal_low),
        goal_high=tuple(float(v) for v in env.goal_high),
    )


def make_optimizer() -> optax.GradientTransformation:
    """Adam (Table 2), its step size traced: `update_classifier` takes it from
    `ClassifierHyperparams` (`optim.adam_step`)."""
    return optim.adam()


def init_classifier(
    net: Classifier, opt: optax.GradientTransformation, goal_dim: int, key: jax.Array
) -> ClassifierState:
    """Fresh parameters and Adam state."""
    dummy = jnp.zeros((1, goal_dim), jnp.float32)
    params = net.init(key, dummy, dummy)
    return ClassifierState(params=params, opt_state=opt.init(params))


def head_probs(net: Classifier, params: dict, x: jax.Array, g: jax.Array) -> jax.Array:
    """f_i(x; g) for every head: x (..., d), g (..., d) -> (..., n_heads) in (0, 1)."""
    return jax.nn.sigmoid(net.apply(params, x, g))


def p_pseudo(net: Classifier, params: dict, x: jax.Array, g: jax.Array) -> jax.Array:
    """p_pseudo(x; g) = mean_i f_i(x; g) (SPEC §3): x (..., d), g (..., d) -> (...,)."""
    return head_probs(net, params, x, g).mean(axis=-1)


def log_p_pseudo(
    net: Classifier, params: dict, x: jax.Array, g: jax.Array
) -> tuple[jax.Array, jax.Array]:
    """(log p_pseudo, log(1 - p_pseudo)) from the logits, exact where p is ~0 or ~1.

    log p = logsumexp_i(log sigmoid(z_i)) - log N, and likewise with -z_i. Far from every
    positive the heads' probabilities underflow float32 long before their logits stop
    ranking states, so costs built on these keep that ranking (clipping p would flatten it).

    Returns:
      two arrays (...,).
    """
    logits = net.apply(params, x, g)  # (..., N)
    log_n = jnp.log(logits.shape[-1])
    log_p = jax.nn.logsumexp(jax.nn.log_sigmoid(logits), axis=-1) - log_n
    log_q = jax.nn.logsumexp(jax.nn.log_sigmoid(-logits), axis=-1) - log_n
    return log_p, log_q


def make_reward_fn(net: Classifier, params: dict) -> RewardFn:
    """D2C's intrinsic reward r = p_pseudo(phi(s_{t+1}); g) (paper §4.4).

    The parameters are wrapped in stop_gradient: the reward is data for SAC, never a
    path for gradients into the classifier.

    Returns:
      reward_fn(ag_next (..., d), goal (..., d)) -> (...,) in (0, 1).
    """
    frozen = jax.lax.stop_gradient(params)

    def reward_fn(ag_next: jax.Array, goal: jax.Array) -> jax.Array:
        return jax.lax.stop_gradient(p_pseudo(net, frozen, ag_next, goal))

    return reward_fn


# --- Eq. 5 ----------------------------------------------------------------------------


def mutual_information(p_i: jax.Array, p_j: jax.Array) -> jax.Array:
    """Batch estimate of MI between two heads (SPEC §3, DivDis).

    Each head is a 2-way distribution [p, 1 - p] per point; the joint is
    P(a, c) = mean_x p_i(a|x) p_j(c|x), the marginals are its sums (= batch means), and
    MI = sum_{a,c} P log(P / (P_i P_j)).

    Args:
      p_i: (B,) probabilities of head i.
      p_j: (B,) probabilities of head j.
    Returns:
      () the mutual information in nats.
    """
    p_i = jnp.clip(p_i, _P_CLIP, 1.0 - _P_CLIP)
    p_j = jnp.clip(p_j, _P_CLIP, 1.0 - _P_CLIP)
    dist_i = jnp.stack([p_i, 1.0 - p_i], axis=-1)  # (B, 2)
    dist_j = jnp.stack([p_j, 1.0 - p_j], axis=-1)  # (B, 2)
    joint = jnp.einsum("ba,bc->ac", dist_i, dist_j) / p_i.shape[0]  # (2, 2)
    marg_i = joint.sum(axis=1, keepdims=True)  # (2, 1)
    marg_j = joint.sum(axis=0, keepdims=True)  # (1, 2)
    return jnp.sum(joint * (jnp.log(joint) - jnp.log(marg_i) - jnp.log(marg_j)))


def mean_pairwise_mi(probs: jax.Array) -> jax.Array:
    """Mean over head pairs i < j of MI(f_i, f_j): probs (B, n_heads) -> ()."""
    pairs = list(itertools.combinations(range(probs.shape[-1]), 2))
    if not pairs:  # one head: nothing to diversify
        return jnp.zeros((), probs.dtype)
    return jnp.mean(jnp.stack([mutual_information(probs[:, i], probs[:, j]) for i, j in pairs]))


def marginal_kl(probs: jax.Array, prior: jax.Array | float, group: int = 1) -> jax.Array:
    """DivDis's marginal regulariser: mean_i KL(Bern(mean_b p_i) || Bern(prior)).

    Why: MI alone is minimised by heads that are constant on the unlabelled points. A head
    that says "x is near g" is ~0 on almost every uniform (u, g) pair, so MI never pushes
    the heads apart and p_pseudo stays ~0 in unexplored space (measured: 0.006 on the
    complex maze), which leaves the Eq. 7 curriculum a pure "Euclidean-nearest" rule that
    parks behind walls. Pulling each head's mean prediction towards `prior` makes one head
    take the other consistent hypothesis, "x is unvisited", so the heads disagree there.
    The mean over heads (not the sum) keeps the term's scale independent of N.

    Args:
      probs: (B, n_heads) head probabilities on the unlabelled points.
      prior: the Bernoulli prior in (0, 1) (traced: `ClassifierHyperparams`).
      group: consecutive rows sharing one conditioning goal; the batch mean is taken per
        group (per goal) and the KLs averaged. 1 pools all rows.
    Returns:
      () the KL in nats, averaged over heads (and groups).
    """
    # group = 1 (each u with its own g) is the pooled term: one group of all B rows.
    size = probs.shape[0] if group == 1 else group
    n_groups = probs.shape[0] // size
    grouped = probs[: n_groups * size].reshape(n_groups, size, probs.shape[-1])
    mean = jnp.clip(grouped.mean(axis=1), _P_CLIP, 1.0 - _P_CLIP)  # (n_groups, n_heads)
    kl = mean * jnp.log(mean / prior) + (1.0 - mean) * jnp.log((1.0 - mean) / (1.0 - prior))
    return kl.mean()


def loss(
    cfg: ClassifierConfig,
    net: Classifier,
    hp: ClassifierHyperparams,
    params: dict,
    batch: ClassifierBatch,
) -> tuple[jax.Array, Metrics]:
    """D2C Eq. 5 plus DivDis's marginal term.

    Sum over heads of the BCEs (means over the batch)
    + lambda * (mean pair MI + mu * marginal KL), lambda = hp.diversity_weight, mu =
    hp.marginal_weight (`marginal_kl`, DEVIATIONS.md). Both terms are the
    diversification, so lambda = 0 turns off both.

    Args:
      cfg: classifier config (the marginal term's group).
      net: the classifier module.
      hp: the traced hyperparameters (lambda, mu, the marginal prior).
      params: its parameters.
      batch: negatives, positives, uniform points and their shared conditioning goals.
    Returns:
      (loss (), metrics) with "classifier/{loss,bce_neg,bce_pos,mi,marginal_kl}".
    """
    g = batch.cond_goals
    neg_logits = net.apply(params, batch.negatives, g)  # (B, N)
    pos_logits = net.apply(params, batch.positives, g)  # (B, N)
    uni_logits = net.apply(params, batch.uniform, batch.uniform_goals)  # (B, N)
    # Stable logits-based BCE; sum over heads of the per-head batch means.
    bce_neg = optax.sigmoid_binary_cross_entropy(neg_logits, jnp.zeros_like(neg_logits))
    bce_pos = optax.sigmoid_binary_cross_entropy(pos_logits, jnp.ones_like(pos_logits))
    bce_neg = bce_neg.mean(axis=0).sum()
    bce_pos = bce_pos.mean(axis=0).sum()
    # Diversity on unlabelled points (DivDis): the heads should be independent there.
    uni_probs = jax.nn.sigmoid(uni_logits)
    mi = mean_pairwise_mi(uni_probs)
    marginal = marginal_kl(uni_probs, hp.marginal_prior, cfg.marginal_group)
    diversity = mi + hp.marginal_weight * marginal
    total = bce_neg + bce_pos + hp.diversity_weight * diversity
    metrics = {
        "classifier/loss": total,
        "classifier/bce_neg": bce_neg,
        "classifier/bce_pos": bce_pos,
        "classifier/mi": mi,
        "classifier/marginal_kl": marginal,
    }
    return total, metrics


def update_classifier(
    cfg: ClassifierConfig,
    net: Classifier,
    opt: optax.GradientTransformation,
    hp: ClassifierHyperparams,
    state: ClassifierState,
    batch: ClassifierBatch,
) -> tuple[ClassifierState, Metrics]:
    """One Adam step of size hp.lr on Eq. 5 (deterministic: all sampling is in
    `sample_batch`)."""
    grad_fn = jax.grad(lambda p: loss(cfg, net, hp, p, batch), has_aux=True)
    grads, metrics = grad_fn(state.params)
    params, opt_state = optim.adam_step(opt, hp.lr, grads, state.opt_state, state.params)
    return state.replace(params=params, opt_state=opt_state), metrics


# --- batches -------------------------------------------------------------------------


def sample_conditioning_goals(
    cfg: ClassifierConfig,
    env: GoalEnv,
    key: jax.Array,
    n: int,
    buffer_states: jax.Array | None = None,
    desired_examples: jax.Array | None = None,
) -> jax.Array:
    """n conditioning goals g ~ D_G (SPEC §3).

    "uniform" (default): D_G = D_T = U(goal bounds). "buffer_and_desired": n // 2 rows
    drawn from `buffer_states`, the rest from the desired examples.

    Args:
      cfg: classifier config (cfg.goal_candidates picks D_G).
      env: the environment (goal bounds, clip_goal).
      key: PRNG key.
      n: number of goals.
      buffer_states: (M, d) achieved goals of buffer states; needed by "buffer_and_desired".
      desired_examples: (n_modes, n_per_mode, d) or (E, d); needed by "buffer_and_desired".
    Returns:
      (n, d) conditioning goals.
    """
    if cfg.goal_candidates == "uniform":
        return env.sample_uniform_goals(key, n)
    if cfg.goal_candidates != "buffer_and_desired":
        raise ValueError(f"unknown goal_candidates {cfg.goal_candidates!r}")
    if buffer_states is None or desired_examples is None:
        raise ValueError("goal_candidates='buffer_and_desired' needs buffer states and examples")
    desired = desired_examples.reshape(-1, desired_examples.shape[-1])
    key_buf, key_des = jax.random.split(key)
    n_buf = n // 2
    from_buf = buffer_states[jax.random.randint(key_buf, (n_buf,), 0, buffer_states.shape[0])]
    from_des = desired[jax.random.randint(key_des, (n - n_buf,), 0, desired.shape[0])]
    return jnp.concatenate([from_buf, from_des], axis=0)


def positive_examples(
    env: GoalEnv, cond_goals: jax.Array, c: jax.Array | float, key: jax.Array
) -> jax.Array:
    """g + eps, eps ~ U[-c, c]^d * goal_noise_mask (Eq. 5 positives): (B, d) -> (B, d)."""
    eps = jax.random.uniform(key, cond_goals.shape, minval=-c, maxval=c)
    return cond_goals + eps * jnp.asarray(env.goal_noise_mask, cond_goals.dtype)


def sample_batch(
    cfg: ClassifierConfig,
    env: GoalEnv,
    hp: ClassifierHyperparams,
    buffer_states: jax.Array,
    desired_examples: jax.Array,
    key: jax.Array,
) -> ClassifierBatch:
    """Builds one Eq. 5 batch around the given buffer states.

    Args:
      cfg: classifier config.
      env: the environment.
      hp: the traced hyperparameters (the positives' noise eps).
      buffer_states: (B, d) achieved goals phi(s) sampled from the replay buffer; they
        are the negatives and set the batch size B.
      desired_examples: (n_modes, n_per_mode, d) desired examples (used by D_G only for
        "buffer_and_desired").
      key: PRNG key.
    Returns:
      ClassifierBatch of B rows per term.
    """
    n = buffer_states.shape[0]
    key_g, key_eps, key_u = jax.random.split(key, 3)
    cond = sample_conditioning_goals(cfg, env, key_g, n, buffer_states, desired_examples)
    return ClassifierBatch(
        negatives=buffer_states,
        positives=positive_examples(env, cond, hp.eps, key_eps),
        uniform=env.sample_uniform_goals(key_u, n),
        cond_goals=cond,
        uniform_goals=grouped_goals(cond, cfg.marginal_group),
    )


def grouped_goals(cond_goals: jax.Array, group: int) -> jax.Array:
    """Each of the first ceil(B / group) goals repeated `group` times, cut to B rows.

    (B, d) -> (B, d); group = 1 returns cond_goals itself.
    """
    if group == 1:
        return cond_goals
    n = cond_goals.shape[0]
    return jnp.repeat(cond_goals[: -(-n // group)], group, axis=0)[:n]
