"""What one run of training is: its static `Schedule`, its traced `Hyperparams`, the
`TrainState` the jitted iteration evolves, and the `HostConstants` read once on the host
(SPEC §2). `d2c_jax.training.agent` builds and steps them (and re-exports these names).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import numpy as np
from flax import struct

import envs
from d2c_jax import config as config_lib
from d2c_jax.core import replay, sac
from d2c_jax.curricula import classifier, curriculum, interface


class Schedule(NamedTuple):
    """Static per-iteration counts derived from the config and the env (SPEC §2)."""

    env_steps: int  # E = num_envs * H
    sac_updates: int  # M = round(E * utd), rounded to whole update blocks
    classifier_updates: int  # round(f_iters * E / f_update_every)
    warmup_iterations: int  # ceil(seed_steps / E)
    eval_every: int  # iterations between evaluations
    total_iterations: int  # ceil(total_steps / E)
    rematch_every: int  # iterations between curriculum matchings
    checkpoint_every: int  # iterations between checkpoints


def make_schedule(cfg: config_lib.TrainConfig, horizon: int) -> Schedule:
    """The static schedule of SPEC §2 for `cfg` and an env of this horizon. A curriculum
    that does not use the classifier (the sparse-reward baselines) trains none."""
    e = cfg.num_envs * horizon
    block = sac.block_size(cfg.sac)  # updates come in whole blocks (no cond, see sac_blocks)
    classifier_updates = round(cfg.classifier.iters * e / cfg.classifier.update_every)
    trains_classifier = interface.curriculum_class(cfg).uses_classifier
    return Schedule(
        env_steps=e,
        sac_updates=block * max(1, round(e * cfg.utd / block)),
        classifier_updates=classifier_updates if trains_classifier else 0,
        warmup_iterations=math.ceil(cfg.seed_steps / e),
        eval_every=max(1, math.ceil(cfg.eval_every / e)),
        total_iterations=math.ceil(cfg.total_steps / e),
        rematch_every=max(1, round(cfg.curriculum.rematch_every / e)),
        checkpoint_every=max(1, math.ceil(cfg.checkpoint_every / e)),
    )


@struct.dataclass
class Hyperparams:
    """The shape-keeping hyperparameters the step reads as traced values, not constants
    compiled into the program, so that a sweep can vmap over them (issue 13): the fields
    of `sweep.SWEEPABLE_FIELDS`. Built from the config by `hyperparams`; the structural
    settings (sizes, cadences, rules) stay in the config."""

    sac: sac.SACHyperparams  # learning rates, tau, initial log alpha
    classifier: classifier.ClassifierHyperparams  # learning rate, lambda, mu, prior, eps
    curriculum: curriculum.CurriculumHyperparams  # goal noise, beta, post-success rule
    relabel_prob: jax.Array  # () float32 HER's relabelling probability
    sparse_reward: jax.Array  # () bool the sparse ablation's reward instead of p_pseudo


def hyperparams(cfg: config_lib.TrainConfig) -> Hyperparams:
    """The config's hyperparameter values as scalars (host side)."""
    return Hyperparams(
        sac=sac.hyperparams(cfg.sac),
        classifier=classifier.hyperparams(cfg.classifier),
        curriculum=curriculum.hyperparams(cfg.curriculum),
        relabel_prob=np.float32(cfg.her.relabel_prob),
        sparse_reward=np.bool_(cfg.reward == "sparse"),
    )


@struct.dataclass
class TrainState:
    """Everything one seed's training evolves (leading seed axis when vmapped).

    Episodes restart from reset every iteration (SPEC §2: whole episodes per
    iteration), so no env state persists between iterations; the curriculum pool is the
    replay buffer's most recent episodes.
    """

    sac: sac.SACState
    classifier: classifier.ClassifierState
    replay: replay.ReplayState
    hparams: Hyperparams  # () leaves: what a sweep vmaps over (set by the config, never
    # learned: checkpoints leave them out and a resumed run takes them from config.json)
    curriculum_state: object  # the curriculum's own state (`interface.Curriculum.init`;
    # None for D2C, HER and HGG, whose pool is the replay buffer)
    desired: jax.Array  # (n_modes, examples_per_mode, goal_dim) desired examples, SPEC §1
    curriculum_goals: jax.Array  # (n_slots, goal_dim) the goals of the last matching
    matching_metrics: dict  # () float32 each: "curriculum/*" metrics of the last matching
    key: jax.Array  # () PRNG key
    iteration: jax.Array  # () int32 iterations done
    env_steps: jax.Array  # () int32 env steps done


class HostConstants(NamedTuple):
    """Env facts the step needs, computed once on the host (never inside the trace)."""

    start_goal: np.ndarray  # (goal_dim,) phi of the start state, the warm-up centre
    start_obs: np.ndarray | None  # (obs_dim,) a start observation, only for "+Value" V(s0, g)


def host_constants(env: envs.GoalEnv, needs_start_obs: bool = False) -> HostConstants:
    """Reads the start state on the host: `env.start_goal` may reset the env and convert
    the result to numpy, which a traced step cannot do (it crashed Sawyer before). The
    start observation costs a compiled reset, so only a curriculum that reads it (the
    "+Value" ablation, VDS) gets one."""
    start_obs = None
    if needs_start_obs:
        zero_goal = np.zeros(env.goal_dim, np.float32)
        start = jax.jit(env.reset_with_goal)(jax.random.key(0), zero_goal)
        start_obs = np.asarray(start.obs, np.float32)
    return HostConstants(start_goal=np.asarray(env.start_goal, np.float32), start_obs=start_obs)
