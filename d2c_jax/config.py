"""Frozen configuration dataclasses for d2c_jax (SPEC.md §2-§5, paper Table 2).

Every field has a one-line docstring. Configs are never mutated: override with
`dataclasses.replace`. Env physics settings live in `envs/`, not here; the presets
live in `d2c_jax.presets` and are re-exported here (`config.preset(env, name)`).
"""

from __future__ import annotations

import dataclasses
import types
from typing import Literal, Mapping

# The baselines' sections, fields of TrainConfig; `config.HGGConfig` etc. stay importable.
from d2c_jax.baseline_config import HGGConfig, OutpaceConfig, TeachersConfig  # noqa: F401


@dataclasses.dataclass(frozen=True)
class EnvSettings:
    """One env's RL settings: its row of Table 3 and its schedule (SPEC §2, §8).

    The env's own facts (phi, radius, the horizon H, goal points) stay in `envs/`.
    """

    n_heads: int
    """Classifier heads N (Table 3 'heads')."""
    diversity_weight: float
    """Diversity weight lambda of Eq. 5 (Table 3 'lambda')."""
    eps: float
    """Table 3 'eps': the presets' classifier.eps (Eq. 5) and curriculum.goal_noise."""
    classifier_every: int
    """Env steps per classifier round (Table 3 'f every')."""
    total_steps: int
    """Env steps of a paper run (SPEC §2)."""
    seed_steps: int
    """Env steps of random actions at the start (SPEC §2)."""
    post_success_range: float
    """Post-success range r: half-width of the candidate noise (SPEC §6)."""


# Table 3's rows (SPEC §8) with SPEC §2's schedules. The config classes' defaults below
# are the mazes' row: TrainConfig() is medium_maze's paper preset.
_MAZE = EnvSettings(n_heads=2, diversity_weight=1.0, eps=0.5, classifier_every=2000,
                    total_steps=1_000_000, seed_steps=2000, post_success_range=2.5)  # fmt: skip
_ANT = EnvSettings(n_heads=2, diversity_weight=2.0, eps=1.0, classifier_every=4500,
                   total_steps=3_000_000, seed_steps=4000, post_success_range=2.5)  # fmt: skip
_SAWYER = EnvSettings(n_heads=2, diversity_weight=1.0, eps=0.025, classifier_every=3000,
                      total_steps=3_000_000, seed_steps=4000, post_success_range=0.1)  # fmt: skip
# env id -> its settings, in the order of envs.ENV_NAMES (read-only).
ENV_SETTINGS: Mapping[str, EnvSettings] = types.MappingProxyType({
    "complex_maze": _MAZE, "medium_maze": _MAZE, "spiral_maze": _MAZE, "ant": _ANT,
    "sawyer_push": _SAWYER, "sawyer_pick_place": _SAWYER,
})  # fmt: skip


def env_settings(env: str) -> EnvSettings:
    """The settings of env `env`.

    Raises:
      ValueError: for an unknown env; the message lists the valid ids.
    """
    if env not in ENV_SETTINGS:
        raise ValueError(f"unknown env {env!r}; valid ids: {', '.join(ENV_SETTINGS)}")
    return ENV_SETTINGS[env]


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
    """Update the target critic every this many SAC updates (Table 2 counts updates)."""
    actor_update_every: int = 2
    """Update the actor and alpha every this many SAC updates (Table 2 counts updates)."""
    init_alpha: float = 0.3
    """Initial entropy temperature alpha."""
    target_entropy: float | None = None
    """Target policy entropy; None means -action_dim."""
    learn_alpha: bool = True
    """Learn log alpha (False keeps alpha = init_alpha; probe tests use this)."""
    clip_target: bool = False
    """Clip the soft TD target to the return's range [0, 1/(1 - gamma)] of rewards in
    [0, 1], as HER implementations clip it (off: the paper's SAC)."""
    critic_layer_norm: bool = False
    """LayerNorm after each hidden Dense of the critics (off: the paper's SAC)."""
    bounded_critic: bool = False
    """Each critic outputs 1/(1 - gamma) * sigmoid(raw), inside the return's range of rewards
    in [0, 1], so it cannot extrapolate below 0 on unseen goals (off: the paper's linear
    output)."""
    terminal_on_success: bool = False
    """The critic stops bootstrapping where s_{t+1} reaches the (relabelled) goal, as
    OUTPACE's code does (done_on_success, consider_done_true_in_critic); off: SPEC §4's
    no terminal. Curricula whose own code ends there (OUTPACE) always do."""
    relative_goal: bool = False
    """Actor and critic see the goal as its offset g - phi(s) from the achieved goal, in
    normalised units, instead of g itself (HIRO's low-level input; off: SPEC §4's input)."""
    actor_mean_reg: float = 0.0
    """Weight lambda of lambda * sum over action dims of u^2, the actor's pre-tanh mean,
    added to J_pi (the Gaussian-mean regulariser of the original SAC code, 1e-3 there; off:
    SPEC §4's J_pi). Where tanh saturates, neither the critic's gradient nor the noise
    reaches u any more; this term still pulls it back."""
    log_std_min: float = -10.0
    """Lower end of the smooth log-std squashing."""
    log_std_max: float = 2.0
    """Upper end of the smooth log-std squashing."""


@dataclasses.dataclass(frozen=True)
class ReplayConfig:
    """Episode-structured replay buffer (SPEC §4)."""

    capacity: int = 3_000_000
    """Capacity in transitions (rounded down to whole episodes)."""
    walk_fraction: float = 0.0
    """Share of each SAC batch from random-walk transitions (OUTPACE: 0.2; 0: uniform)."""


@dataclasses.dataclass(frozen=True)
class HERConfig:
    """Hindsight relabelling: the 'future' strategy (SPEC §4), optionally with 'random'."""

    relabel_prob: float = 0.8
    """Probability that a sampled transition's goal is replaced by a future achieved goal."""
    min_future_radii: float = 0.0
    """A future goal within this many success radii of phi(s_t), an outcome already reached
    at s_t, is not used: the transition keeps its own goal. 0: every one is (SPEC §4)."""
    random_prob: float = 0.0
    """Probability that a sampled transition's goal is instead the achieved goal of a state
    drawn uniformly from the whole buffer (HER's "random" strategy); relabel_prob +
    random_prob <= 1, the rest keep their own goal. 0: off, future-only (SPEC §4)."""
    n_step: int = 1
    """Steps n of each SAC target's return along the stored episode (uncorrected n-step
    return, cut at the episode's end); 1: the one-step target of the paper (SPEC §4)."""


@dataclasses.dataclass(frozen=True)
class ClassifierConfig:
    """The diversified conditional classifier ensemble (SPEC §3, Eq. 5)."""

    n_heads: int = _MAZE.n_heads
    """Number of heads N on the shared trunk."""
    hidden_sizes: tuple[int, ...] = (256, 256, 256)
    """Widths of the shared trunk (ReLU)."""
    lr: float = 1e-3
    """Adam learning rate."""
    batch_size: int = 512
    """Batch size of each of the three loss terms."""
    diversity_weight: float = _MAZE.diversity_weight
    """lambda of Eq. 5 (0 = no diversification)."""
    marginal_weight: float = 0.0
    """mu: DivDis's marginal regulariser, weighted lambda * mu (0 = Eq. 5 alone, the default)."""
    marginal_prior: float = 0.5
    """Bernoulli prior each head's mean prediction on the unlabelled points is pulled to."""
    marginal_group: int = 1
    """Unlabelled points per conditioning goal in the marginal term: 1 pools it over (u, g)
    pairs; G > 1 pairs G points with each goal and takes the term per goal (rule 6)."""
    negatives: Literal["all", "curriculum_phase"] = "all"
    """Negatives from every stored state, or only from the curriculum phase (OUTPACE)."""
    eps: float = _MAZE.eps
    """Half-width c of the noise on desired goals in Eq. 5's positives (Table 3 'eps')."""
    update_every: int = _MAZE.classifier_every
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
    post_success_range: float = _MAZE.post_success_range
    """r: half-width of the candidate noise around the reached state (SPEC §6)."""
    post_success_rule: Literal["argmax", "outpace"] = "argmax"
    """'argmax' of the candidates' p (SPEC §6), or OUTPACE's thresholded softmax sample."""
    post_success_threshold: float = 0.4
    """'outpace': candidates need p >= this, relaxed by `post_success_relax` until one does."""
    post_success_relax: float = 0.02
    """'outpace': step by which the threshold is relaxed."""
    post_success_temperature: float = 0.1
    """'outpace': the qualifying candidates are sampled by softmax(p / temperature)."""
    post_success_switch_every: int = 0
    """After the curriculum goal is reached, also switch goals every this many env steps of
    the episode (0: off)."""
    pool_tail_fraction: float = 1.0
    """Match against the last this fraction of each pool trajectory plus its final state."""
    pool_min_move: float = 0.0
    """Pool episodes whose phi moved at most this from start to end are not candidates."""
    pool_phase: Literal["all", "curriculum_phase"] = "all"
    """Matching candidates from every state of a pool episode, or only from s_0..s_w, the
    states reached pursuing the curriculum goal (w: its success step; `replay.hold_after`)."""
    pool_walk_steps: int = 0
    """With pool_phase 'curriculum_phase' (required when > 0): also keep this many steps of
    the post-success walk, s_0..s_{w+k}, so the candidates reach a little past the states
    the policy reached on its own."""
    archive_size: int = 0
    """Pool episodes drawn from the whole buffer, beside the P most recent."""
    archive_rarity: float = 0.0
    """w: archive episodes are drawn with probability proportional to density(phi(s_T))^-w,
    the visitation density of their final state (MEGA's minimum-density idea, soft); 0
    draws uniformly."""
    goal_value_weight: float = 0.0
    """beta: each Eq. 7 edge cost less beta * (1 - gamma) * V(s, g_j+), the critic's value
    of reaching slot j's desired example from candidate s (0: Eq. 7 alone)."""
    rematch_every: int = 2000
    """Env steps between matchings (whole iterations; OUTPACE: every 20 episodes); the envs
    of the iterations in between take the next slots of the held goals in turn."""
    goal_noise: float = _MAZE.eps
    """Half-width c of the U[-c, c] noise added to the matched curriculum goals (SPEC §5's
    eps; every preset: Table 3's eps, the classifier's `eps`)."""
    auction_max_iters: int = 100_000
    """Iteration cap of the auction matcher (also `matching.auction`'s default)."""


# --- the whole run ---------------------------------------------------------------

# The curricula `--algo` selects (d2c_jax.curricula.interface): D2C, and the paper's
# baselines built on the same SAC, HER, trajectory pool and auction.
ALGO_NAMES = ("d2c", "her", "hgg", "outpace", "currot", "plr", "alp_gmm", "vds")
# The reward each algorithm trains with; None: `TrainConfig.reward` decides (D2C's
# intrinsic reward or its sparse ablation). Paper appendix A.1: every baseline but
# OUTPACE is trained with the sparse reward; OUTPACE's "intrinsic" reward is its own (AIM).
ALGO_REWARDS: dict[str, str | None] = {
    "d2c": None, "her": "sparse", "hgg": "sparse", "outpace": "intrinsic",
    "currot": "sparse", "plr": "sparse", "alp_gmm": "sparse", "vds": "sparse",
}  # fmt: skip
# The teachers: one new goal per episode from the goal bounds, scored on its return.
TEACHER_ALGOS = ("currot", "plr", "alp_gmm", "vds")


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """One D2C run (SPEC §2, §7): the env, the schedules and every component's config."""

    env: str = "medium_maze"
    """Environment id (envs.ENV_NAMES)."""
    preset: str = "paper"
    """Name of the preset this config came from (recorded in config.json)."""
    seed: int = 0
    """First seed S; vmapped seeds are S..S+num_seeds-1."""
    num_seeds: int = 1
    """Number of seeds trained together in one vmapped program."""
    total_steps: int = _MAZE.total_steps
    """Env steps to train for (rounded up to whole iterations)."""
    num_envs: int = 20
    """Parallel episodes per iteration; E = num_envs * horizon env steps per iteration."""
    utd: float = 1.0
    """SAC updates per env step: M = round(E * utd) updates per iteration."""
    seed_steps: int = _MAZE.seed_steps
    """Env steps of random actions at the start (whole iterations: ceil(seed_steps / E))."""
    eval_every: int = 10_000
    """Env steps between evaluations: every ceil(eval_every / E) iterations (and once at
    the end)."""
    eval_episodes: int = 10
    """Evaluation episodes per mode."""
    checkpoint_every: int = 50_000
    """Env steps between checkpoints: every ceil(checkpoint_every / E) iterations (and at
    the end, and on a signal). Default: 25 paper iterations of medium_maze (20 x H 100)."""
    checkpoint_minutes: float = 15.0
    """Also checkpoint at the end of the first iteration that finds this many minutes of
    wall clock passed since the last checkpoint (0 = off), so a run killed without a
    signal loses at most about this much work. Which iterations get one varies; the
    results do not."""
    algo: Literal["d2c", "her", "hgg", "outpace", "currot", "plr", "alp_gmm", "vds"] = "d2c"
    """The curriculum and its reward: D2C, or a baseline (`ALGO_NAMES`); `with_algo`."""
    reward: Literal["intrinsic", "sparse"] = "intrinsic"
    """D2C's intrinsic reward p_pseudo(phi(s'); g), or the sparse ablation."""
    sac: SACConfig = dataclasses.field(default_factory=SACConfig)
    """Goal-conditioned SAC."""
    replay: ReplayConfig = dataclasses.field(default_factory=ReplayConfig)
    """Replay buffer."""
    her: HERConfig = dataclasses.field(default_factory=HERConfig)
    """Hindsight relabelling."""
    classifier: ClassifierConfig = dataclasses.field(default_factory=ClassifierConfig)
    """Classifier ensemble."""
    curriculum: CurriculumConfig = dataclasses.field(default_factory=CurriculumConfig)
    """Curriculum."""
    hgg: HGGConfig = dataclasses.field(default_factory=HGGConfig)
    """HGG's matching cost (`--algo hgg`)."""
    outpace: OutpaceConfig = dataclasses.field(default_factory=OutpaceConfig)
    """OUTPACE's classifier, potential and cost (`--algo outpace`)."""
    teachers: TeachersConfig = dataclasses.field(default_factory=TeachersConfig)
    """The goal-space teachers (`--algo currot|plr|alp_gmm|vds`)."""
    sweep: tuple[tuple[str, tuple], ...] = ()
    """Hyperparameter arms (issue 13): (dotted field, values) pairs whose Cartesian
    product, times the num_seeds seeds, runs as one program (`d2c_jax.training.sweep`);
    the swept fields' own values above are then unused. () = one arm."""


def iteration_steps(env: str, num_envs: int, iterations: int) -> int:
    """Env steps of `iterations` iterations of `num_envs` episodes of env `env` (SPEC §2)."""
    import envs  # here: config.py stays importable without jax (`train.py --help`)

    return iterations * num_envs * envs.horizon(env)


# The presets live in d2c_jax/presets.py; these names stay importable from here, the
# path the contract names (`config.preset(env, name)`). Resolved on first use, because
# presets.py imports this module's classes.
_PRESET_EXPORTS = (
    "PRESET_NAMES", "paper_preset", "quick_preset", "tiny_preset", "preset", "with_algo",
    "with_outpace_exploration",
)  # fmt: skip


# Reading config.json dicts and dotted field paths live in d2c_jax/config_io.py, which imports
# this module; its names stay importable from here too, resolved on first use likewise.
_CONFIG_IO_EXPORTS = (
    "from_dict", "replace_field", "get_field", "unknown_fields", "field_docs",
)  # fmt: skip


def __getattr__(name: str):
    if name in _PRESET_EXPORTS:
        from d2c_jax import presets

        return getattr(presets, name)
    if name in _CONFIG_IO_EXPORTS:
        from d2c_jax import config_io

        return getattr(config_io, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
