"""The goal after the current one is reached (SPEC §6; paper Alg. 1 lines 8-9).

C candidates phi(s_t) + U[-r, r] around where the goal was reached are scored, and one
becomes the episode's next goal: D2C scores them by max over modes k of p_pseudo(c; g_k);
OUTPACE by its own classifier (`outpace.py`), through the same `walk_goal`. Pure and
vmappable over envs.
"""

from __future__ import annotations

from typing import Callable

import jax
import jax.numpy as jnp

from d2c_jax.config import CurriculumConfig
from d2c_jax.curricula.classifier import Classifier, p_pseudo
from d2c_jax.curricula.curriculum import CurriculumHyperparams, hyperparams, uniform_noise
from envs import GoalEnv


def walk_candidates(env: GoalEnv, achieved_goal: jax.Array, key, n: int, r) -> jax.Array:
    """n candidates phi(s_t) + U[-r, r] * mask, clipped to the goal bounds: (n, d)."""
    shape = (n, achieved_goal.shape[-1])
    return env.clip_goal(achieved_goal + uniform_noise(env, key, shape, r))


def mode_scores(env: GoalEnv, net: Classifier, params: dict, cands: jax.Array) -> jax.Array:
    """SPEC §6's score of candidates (n, d): max over modes k of p_pseudo(c; g_k), (n,)."""
    modes = jnp.asarray(env.goal_points, jnp.float32)  # (n_modes, d)
    return p_pseudo(net, params, cands[:, None, :], modes[None]).max(axis=-1)


def candidate_scores(
    env: GoalEnv, net: Classifier, params: dict, achieved_goal: jax.Array, key, n: int, r: float
) -> tuple[jax.Array, jax.Array]:
    """n candidates (`walk_candidates`) and their SPEC §6 scores (`mode_scores`).

    Returns:
      candidates (n, d) and scores (n,).
    """
    cands = walk_candidates(env, achieved_goal, key, n, r)
    return cands, mode_scores(env, net, params, cands)


def relaxed_threshold(scores: jax.Array, threshold: float, relax: float) -> jax.Array:
    """() the first of threshold, threshold - relax, ... that some score reaches (OUTPACE)."""
    shortfall = jnp.maximum(threshold - scores.max(), 0.0)
    return threshold - relax * jnp.ceil(shortfall / relax - 1e-6)


def walk_goal(
    cfg: CurriculumConfig,
    env: GoalEnv,
    achieved_goal: jax.Array,
    key: jax.Array,
    hp: CurriculumHyperparams,
    score_fn: Callable[[jax.Array, jax.Array], jax.Array],
) -> jax.Array:
    """The goal after the current one is reached, for any candidate score.

    C = cfg.post_success_candidates candidates (`walk_candidates`, r =
    hp.post_success_range) scored by score_fn(candidates (C, d), key) -> (C,). Rule
    "argmax": the best one wins. Rule "outpace" (OUTPACE's random walk): the candidates
    scoring at least the threshold (relaxed step by step until one does) are sampled by
    softmax(score / T), so the walk heads for uncertain places without always taking the
    same one. Vmappable. Returns (d,) the new goal.
    """
    cands = walk_candidates(env, achieved_goal, key, cfg.post_success_candidates,
                            hp.post_success_range)  # fmt: skip
    scores = score_fn(cands, jax.random.fold_in(key, 2))
    if cfg.post_success_rule == "argmax":
        return cands[jnp.argmax(scores)]
    threshold = relaxed_threshold(scores, hp.post_success_threshold, hp.post_success_relax)
    logits = jnp.where(scores >= threshold - 1e-6, scores / hp.post_success_temperature, -jnp.inf)
    return cands[jax.random.categorical(jax.random.fold_in(key, 1), logits)]


def post_success_goal(
    cfg: CurriculumConfig,
    env: GoalEnv,
    net: Classifier,
    params: dict,
    achieved_goal: jax.Array,
    key: jax.Array,
    hp: CurriculumHyperparams | None = None,
) -> jax.Array:
    """D2C's goal after the current one is reached (SPEC §6, Alg. 1 lines 8-9): `walk_goal`
    with SPEC §6's score, max over modes k of p_pseudo(c; g_k) (`mode_scores`).

    Args:
      cfg: curriculum config (the rule and the candidate count).
      env: the environment; net, params: the classifier.
      achieved_goal: (d,) phi(s_t) where the goal was reached.
      key: PRNG key.
      hp: the traced range, threshold, relaxing step and temperature; None:
        `hyperparams(cfg)`.
    Returns:
      (d,) the new goal.
    """
    hp = hyperparams(cfg) if hp is None else hp
    return walk_goal(
        cfg, env, achieved_goal, key, hp, lambda cands, _: mode_scores(env, net, params, cands)
    )
