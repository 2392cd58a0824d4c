"""The config sections of the paper's baselines (`--algo hgg|outpace|currot|plr|alp_gmm|
vds`; docs/BASELINES.md cites each default): fields of `config.TrainConfig`, and
importable from `d2c_jax.config` as they always were.

Every field has a one-line docstring (`config_io.field_docs` reads them for `--help`).
"""

from __future__ import annotations

import dataclasses
from typing import Literal


@dataclasses.dataclass(frozen=True)
class HGGConfig:
    """HGG's matching cost (Ren et al. 2019; docs/BASELINES.md), read with `--algo hgg`."""

    init_distance_weight: float = 3.0
    """c: weight of the distance between a trajectory's first achieved goal and the start's
    (HGG's `hgg_c`, default 3)."""
    lipschitz: float = 5.0
    """L: the value's Lipschitz constant, which scales the value term by D (1 - gamma) / L
    (HGG's `hgg_L`, default 5; OUTPACE's copy used 50)."""


@dataclasses.dataclass(frozen=True)
class OutpaceConfig:
    """OUTPACE (Cho, Lee & Kim 2023; `--algo outpace`): its meta-NML classifier, its AIM
    potential and its curriculum cost. Defaults: the authors' maze settings
    (outpace_official config/config_outpace.yaml; docs/BASELINES.md cites each)."""

    nml_hidden_sizes: tuple[int, ...] = (2048, 2048)
    """Meta-NML classifier MLP widths."""
    nml_input_scale: float = 1.0
    """Meta-NML inputs (and their distances) are multiplied by this (1/0.05 on Sawyer)."""
    nml_inner_step: float = 0.01
    """SGD step of the one adaptation step (MAML inner loop, and at query time)."""
    nml_context_points: int = 63
    """Points besides the query in an adaptation batch (points_per_task 64)."""
    nml_query_weight_inner: float = 1.0 / 32
    """The query's weight in an adaptation batch."""
    nml_query_weight_outer: float = 0.5
    """The query's weight in the meta-test loss."""
    nml_lr: float = 1e-3
    """Adam step of the meta-training."""
    nml_tasks_per_step: int = 16
    """MAML tasks averaged per Adam step (accumulation_steps)."""
    nml_steps_per_round: int = 64
    """Adam steps per meta-training round (one epoch of 1024 tasks / 16)."""
    nml_every: int = 3000
    """Env steps between meta-training rounds (whole iterations)."""
    nml_initial_rounds: int = 3
    """Rounds in the first iterations (num_initial_meta_epochs)."""
    nml_train_points: int = 512
    """Query points drawn per round, half negatives, half positives."""
    nml_test_points: int = 2048
    """Meta-test and fine-tuning points, half negatives, half positives."""
    aim_members: int = 5
    """AIM discriminator ensemble size."""
    aim_hidden_sizes: tuple[int, ...] = (64, 64)
    """Each member's MLP widths (tanh)."""
    aim_lr: float = 1e-4
    """Adam step of each member."""
    aim_steps_per_1000: int = 10
    """AIM updates per 1000 env steps."""
    aim_batch_size: int = 512
    """AIM batch (HER-relabelled curriculum-phase transitions)."""
    aim_lipschitz: float = 0.1
    """Largest change of the potential between consecutive states."""
    aim_penalty: float = 25.0
    """Weight of the Lipschitz hinge (lambda_coef; 50 on the spiral maze)."""
    aim_target_noise: float = 0.1
    """Std of the target point x+ = g + N(0, s^2) (0.01 on Sawyer)."""
    aim_reward_offset: float = 0.1
    """Reward normalisers: max + offset and std + offset of the last block's potentials."""
    cost_lipschitz: float = 50.0
    """L of the curriculum cost's AIM term D (1 - gamma) / L (hgg_L; 0.5 on Sawyer push)."""
    goal_noise_std: float = 0.5
    """Std of the Gaussian noise on each matched goal (0.05 on Sawyer)."""


@dataclasses.dataclass(frozen=True)
class TeachersConfig:
    """The goal-space teachers of psclklnk/currot (`--algo currot|plr|alp_gmm|vds`), with
    the defaults of its maze ("sparse goal reaching") experiment (docs/BASELINES.md)."""

    plr_replay_rate: float = 0.55
    """PLR: probability of replaying a buffered goal rather than drawing a new one."""
    plr_buffer_size: int = 100
    """PLR: goals kept with their scores."""
    plr_beta: float = 0.15
    """PLR: temperature of the rank prioritisation."""
    plr_rho: float = 0.45
    """PLR: weight of the staleness distribution in the replay mixture."""
    alp_random_ratio: float = 0.2
    """ALP-GMM: share of goals drawn uniformly over the goal bounds."""
    alp_fit_rate: int = 200
    """ALP-GMM: episodes between mixture fits, and the (goal, ALP) rows each fit uses."""
    alp_history: int = 500
    """ALP-GMM: past episodes searched for the nearest earlier goal."""
    alp_max_components: int = 10
    """ALP-GMM: mixtures of 2..this many components are fitted; the least AIC is kept."""
    alp_tol: float = 1e-3
    """ALP-GMM: EM stops when the mean log-likelihood changes by less than this."""
    alp_reg_covar: float = 1e-6
    """ALP-GMM: added to every covariance's diagonal."""
    alp_max_iter: int = 100
    """ALP-GMM: EM iterations at most."""
    vds_members: int = 5
    """VDS: Q-functions in the ensemble."""
    vds_hidden_sizes: tuple[int, ...] = (128, 128, 128)
    """VDS: each Q-function's widths (tanh)."""
    vds_lr: float = 5e-4
    """VDS: Adam step of the ensemble."""
    vds_updates_per_10k: int = 800
    """VDS: TD updates per 10,000 env steps (10 epochs x 80 batches per 10k steps)."""
    vds_batch_size: int = 512
    """VDS: transitions per TD update and member."""
    vds_candidates: int = 1000
    """VDS: uniform candidate goals scored by the ensemble's disagreement."""
    currot_particles: int = 500
    """CURROT: particles representing the curriculum (and the success buffer's size)."""
    currot_episodes_per_update: int = 50
    """CURROT: episodes between particle updates (rounded up to whole iterations)."""
    currot_delta: float = 0.8
    """CURROT: the performance threshold, a success rate (converted to the critic's scale)."""
    currot_trust_region: float = 0.0481
    """CURROT: the most a particle moves per update, as a fraction of the goal box's
    diagonal (the reference's sqrt(1.5) in its 18 x 18 maze)."""
    currot_candidates: int = 100
    """CURROT: candidate moves per particle and update."""
    currot_performance: Literal["returns", "critic"] = "returns"
    """CURROT: the performance estimate, the reference's regression of episode returns or
    the critic's V(s0, g) (docs/DEVIATIONS.md, "CURROT": the critic overrates goals)."""
