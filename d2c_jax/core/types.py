"""Types shared across layers: metrics, reward functions and SAC batches."""

from __future__ import annotations

import dataclasses
from typing import Callable, NamedTuple

import jax
import numpy as np

# A flat dict of scalar metrics, keys like "sac/critic_loss" (ARCHITECTURE.md conventions).
Metrics = dict[str, jax.Array]

# reward_fn(next achieved goal (..., goal_dim), goal (..., goal_dim)) -> reward (...,).
RewardFn = Callable[[jax.Array, jax.Array], jax.Array]


def float32_scalars(cls, cfg, **values):
    """A hyperparameter struct `cls` (traced values, issue 13) of float32 scalars: each
    field is `values[name]` where given, else the config field of the same name."""
    return cls(**{
        f.name: np.float32(values[f.name] if f.name in values else getattr(cfg, f.name))
        for f in dataclasses.fields(cls)
    })  # fmt: skip


class Batch(NamedTuple):
    """A SAC training batch (raw obs and goals; SAC normalises them)."""

    obs: jax.Array  # (B, obs_dim) s_t
    action: jax.Array  # (B, action_dim) a_t
    reward: jax.Array  # (B,) r = reward_fn(phi(s_{t+1}), goal); n-step: the n-step sum
    next_obs: jax.Array  # (B, obs_dim) s_{t+1}; n-step: s_{t+n'}
    goal: jax.Array  # (B, goal_dim) the (possibly relabelled) goal
    mask: jax.Array  # (B,) bootstrap weight: 0 at a true terminal, else 1; n-step: gamma^(n'-1)
