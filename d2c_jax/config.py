"""Frozen configuration dataclasses for d2c_jax (SPEC.md §2-§5, paper Table 2).

Every field has a one-line docstring. Configs are never mutated: override with
`dataclasses.replace`. Env physics settings live in `envs/`, not here.
"""

from __future__ import annotations

import dataclasses
from typing import Literal


@dataclasses.dataclass(frozen=True)
class SACConfig:
    """Goal-conditioned SAC (SPEC §4, paper Table 2)."""

    hidden_sizes: tuple[int, ...] = (512, 512, 512)
    """Hidden layer widths of the actor and of each twin critic (ReLU)."""
    gamma: float = 0.99
    """Discount factor."""
    batch_size: int = 512
    """Transitions per SAC update."""
    actor_lr: float = 1e-4
    """Adam learning rate of the actor."""
    critic_lr: float = 1e-4
    """Adam learning rate of the twin critic."""
    alpha_lr: float = 1e-4
    """Adam learning rate of log alpha."""
    tau: float = 0.01
    """Polyak coefficient of the target critic update."""
    target_update_every: int = 2
    """Update the target critic every this many updates."""
    actor_update_every: int = 2
    """Update the actor and alpha every this many updates."""
    init_alpha: float = 0.3
    """Initial entropy temperature alpha."""
    target_entropy: float | None = None
    """Target policy entropy; None means -action_dim."""
    learn_alpha: bool = True
    """Learn log alpha (False keeps alpha = init_alpha; probe tests use this)."""
    log_std_min: float = -10.0
    """Lower end of the smooth log-std squashing."""
    log_std_max: float = 2.0
    """Upper end of the smooth log-std squashing."""


@dataclasses.dataclass(frozen=True)
class ReplayConfig:
    """Episode-structured replay buffer (SPEC §4)."""

    capacity: int = 3_000_000
    """Capacity in transitions (rounded down to whole episodes)."""


@dataclasses.dataclass(frozen=True)
class HERConfig:
    """Hindsight relabelling, 'future' strategy (SPEC §4)."""

    relabel_prob: float = 0.8
    """Probability that a sampled transition's goal is replaced by a future achieved goal."""


@dataclasses.dataclass(frozen=True)
class ClassifierConfig:
    """The diversified conditional classifier ensemble (SPEC §3, Eq. 5)."""

    n_heads: int = 2
    """Number of heads N on the shared trunk."""
    hidden_sizes: tuple[int, ...] = (256, 256, 256)
    """Widths of the shared trunk (ReLU)."""
    lr: float = 1e-3
    """Adam learning rate."""
    batch_size: int = 512
    """Batch size of each of the three loss terms."""
    diversity_weight: float = 1.0
    """lambda of Eq. 5 (0 = no diversification)."""
    eps: float = 0.5
    """Half-width c of the uniform noise added to desired goals (Table 3 'eps')."""
    update_every: int = 2000
    """Env steps per classifier round (Table 3 'f every')."""
    iters: int = 16
    """Classifier updates per round (Table 3 'f iters')."""
    goal_candidates: Literal["uniform", "buffer_and_desired"] = "uniform"
    """Distribution D_G of conditioning goals."""


@dataclasses.dataclass(frozen=True)
class CurriculumConfig:
    """Curriculum by bipartite matching (SPEC §5-§6)."""

    n_slots: int = 20
    """K: curriculum goals chosen per iteration."""
    pool_size: int = 100
    """P: most recent episodes whose trajectories are matched against (P >= K)."""
    cost_stride: int = 4
    """Subsample pool trajectories to every this-th step plus the final one."""
    examples_per_mode: int = 100
    """Desired examples per mode (mode point + N(0, (radius/2)^2))."""
    variant: Literal["d2c", "value", "none"] = "d2c"
    """'d2c' (Eq. 7), 'value' (+Value ablation), 'none' (goals from desired examples)."""
    post_success_candidates: int = 16
    """C: candidates scored when a goal is reached (SPEC §6)."""
    post_success_range: float = 2.5
    """r: half-width of the candidate noise around the reached state (SPEC §6)."""
    auction_max_iters: int = 100_000
    """Iteration cap of the auction matcher."""
