"""Valid ranges of every config field, checked before anything compiles (issue 10 §1b).

`validate(cfg)` walks every leaf field of a `TrainConfig` (through every nested section)
and checks it against its range: the one its type implies (an int is a count >= 1, a
float a finite scale, weight or learning rate >= 0), unless `_RANGE_EXCEPTIONS` names
another; then the constraints between fields. A violation is one line naming the flag as
typed, the value and the valid range; the CLI turns it into exit status 2.
"""

from __future__ import annotations

import dataclasses
import typing
from typing import Literal

from d2c_jax.config import ALGO_REWARDS, TrainConfig
from d2c_jax.training.ranges import (  # the range kinds (tests read them from here too)
    Interval,
    NonEmptyTuple,
    OneOf,
    OrNone,
    Range,
    SweepPairs,
    Text,
)


def validate(cfg: TrainConfig) -> str | None:
    """A one-line description of the first invalid setting, or None.

    Every leaf field (through every nested section) is checked against its range in
    `field_ranges()`: the range its type implies (`_default_range`), unless
    `_RANGE_EXCEPTIONS` names another; then the constraints between fields
    (`cross_field_problem`). The line names the flag as typed, the value and the valid
    range, e.g. `--sac.gamma must be in [0, 1), got 1.5`.
    """
    ranges = field_ranges()
    for path, value in _leaf_values(cfg):
        problem = field_problem(path, value, ranges)
        if problem:
            return problem
    if cfg.sweep:
        return _sweep_problem(cfg)
    return cross_field_problem(cfg)


def _sweep_problem(cfg: TrainConfig) -> str | None:
    """The first problem of a sweep: its fields (`sweep.problem`), then every arm's
    config by the rules of a single run, named by the arm's values."""
    from d2c_jax.training import sweep  # here: sweep imports nothing of this module

    problem = sweep.problem(cfg)
    if problem:
        return problem
    fields = [field for field, _ in cfg.sweep]
    for values, arm in zip(sweep.arm_values(cfg), sweep.arm_configs(cfg), strict=True):
        problem = validate(arm)
        if problem:
            where = " ".join(
                f"{sweep.flag_spelling(f)}={show_value(v)}"
                for f, v in zip(fields, values, strict=True)
            )
            return f"{problem} (in the sweep arm {where})"
    return None


# --- valid ranges (checked by `validate`) -------------------------------------------

_MAX_SEED = 2**32 - 1  # jax.random.key wraps above this: seed 2**32 is seed 0

# Fields whose range is NOT the one their type implies (`_default_range`: an int is a
# count >= 1, a float a finite scale, weight or learning rate >= 0). Keyed by dotted path;
# `tests/test_config.py` checks that every key names a field. A new field whose default
# range is wrong (a probability, a fraction, an int where 0 means "off") goes here.
_RANGE_EXCEPTIONS: dict[str, Range] = {
    # A PRNG seed: 0 is a seed; above 2**32 - 1 jax.random.key wraps around.
    "seed": Interval(0, _MAX_SEED, integer=True),
    # 0 = no random-action warm-up iterations.
    "seed_steps": Interval(0, integer=True),
    # M = round(E * utd) SAC updates per iteration: 0 would never learn.
    "utd": Interval(0, lo_open=True),
    # Discount: 1 makes the critic's fixed point infinite.
    "sac.gamma": Interval(0, 1, hi_open=True),
    # Polyak coefficient: 0 would freeze the target critic.
    "sac.tau": Interval(0, 1, lo_open=True),
    # log alpha = log(init_alpha).
    "sac.init_alpha": Interval(0, lo_open=True),
    # A penalty weight (0: off).
    "sac.actor_mean_reg": Interval(0),
    # An entropy (any sign), or None for -action_dim.
    "sac.target_entropy": OrNone(Interval()),
    # Ends of the log-std squashing (any sign; min < max is a cross-field check).
    "sac.log_std_min": Interval(),
    "sac.log_std_max": Interval(),
    # Probabilities and fractions.
    "her.relabel_prob": Interval(0, 1),
    # A distance in success radii.
    "her.min_future_radii": Interval(0),
    "her.random_prob": Interval(0, 1),
    # Steps of the return: at least the one-step target.
    "her.n_step": Interval(1, integer=True),
    "replay.walk_fraction": Interval(0, 1),
    "curriculum.post_success_threshold": Interval(0, 1),
    "curriculum.pool_tail_fraction": Interval(0, 1),
    # A Bernoulli prior: 0 or 1 make the marginal KL infinite.
    "classifier.marginal_prior": Interval(0, 1, lo_open=True, hi_open=True),
    # Divisors: p / temperature and shortfall / relax.
    "curriculum.post_success_temperature": Interval(0, lo_open=True),
    "curriculum.post_success_relax": Interval(0, lo_open=True),
    # Counts where 0 means "off".
    "curriculum.post_success_switch_every": Interval(0, integer=True),
    "curriculum.archive_size": Interval(0, integer=True),
    "curriculum.pool_walk_steps": Interval(0, integer=True),
    "curriculum.archive_rarity": Interval(0),
    # ALP-GMM fits mixtures of 2 or more components on alp_fit_rate rows.
    "teachers.alp_fit_rate": Interval(2, integer=True),
    "teachers.alp_max_components": Interval(2, integer=True),
    # Probabilities.
    "teachers.plr_replay_rate": Interval(0, 1),
    "teachers.plr_rho": Interval(0, 1),
    "teachers.alp_random_ratio": Interval(0, 1),
    # CURROT: a success rate, and a fraction of the box (0 would never move).
    "teachers.currot_delta": Interval(0, 1),
    "teachers.currot_trust_region": Interval(0, 1, lo_open=True),
    # PLR's rank temperature divides.
    "teachers.plr_beta": Interval(0, lo_open=True),
    # OUTPACE divides by L and by (std + offset).
    "outpace.cost_lipschitz": Interval(0, lo_open=True),
    "outpace.aim_reward_offset": Interval(0, lo_open=True),
    "outpace.nml_input_scale": Interval(0, lo_open=True),
    # HGG's value term is scaled by D (1 - gamma) / L.
    "hgg.lipschitz": Interval(0, lo_open=True),
    # Hyperparameter arms: their fields and values are checked arm by arm (`validate`).
    "sweep": SweepPairs(),
}

# Flags whose name is not the dotted field path with dashes.
_FLAG_NAMES = {"num_seeds": "--seeds"}


def flag_name(path: str) -> str:
    """The flag of the field at dotted `path`: 'sac.batch_size' -> '--sac.batch-size'."""
    return _FLAG_NAMES.get(path) or "--" + path.replace("_", "-")


def _default_range(hint, path: str) -> Range:
    """The range a field's type implies.

    Raises:
      TypeError: for a type without one (give the field a `_RANGE_EXCEPTIONS` entry).
    """
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if hint is bool:  # before int: bool is an int
        return OneOf((True, False))
    if hint is int:  # a count
        return Interval(1, integer=True)
    if hint is float:  # a scale, weight, noise width or learning rate
        return Interval(0)
    if hint is str:
        return Text()
    if origin is Literal:
        return OneOf(args)
    if origin in (typing.Union, type(int | None)) and len(args) == 2 and type(None) in args:
        (inner,) = [a for a in args if a is not type(None)]
        return OrNone(_default_range(inner, path))
    if origin is tuple and len(args) == 2 and args[1] is Ellipsis:
        return NonEmptyTuple(_default_range(args[0], path))
    raise TypeError(
        f"config field {path!r} has type {hint!r}, which has no default range; "
        "add it to config._RANGE_EXCEPTIONS"
    )


def field_ranges(cls=TrainConfig, prefix: str = "") -> dict[str, Range]:
    """The valid range of every leaf field of config dataclass `cls`, by dotted path."""
    hints = typing.get_type_hints(cls)
    ranges: dict[str, Range] = {}
    for field in dataclasses.fields(cls):
        path, hint = prefix + field.name, hints[field.name]
        if isinstance(hint, type) and dataclasses.is_dataclass(hint):
            ranges.update(field_ranges(hint, path + "."))
        elif path in _RANGE_EXCEPTIONS:
            ranges[path] = _RANGE_EXCEPTIONS[path]
        else:
            ranges[path] = _default_range(hint, path)
    return ranges


def _leaf_values(cfg, prefix: str = ""):
    """(dotted path, value) of every leaf field of config dataclass instance `cfg`."""
    for field in dataclasses.fields(cfg):
        value = getattr(cfg, field.name)
        if dataclasses.is_dataclass(value) and not isinstance(value, type):
            yield from _leaf_values(value, prefix + field.name + ".")
        else:
            yield prefix + field.name, value


def show_value(value) -> str:
    """A value as the command line takes it (tuples comma-separated; strings quoted)."""
    if isinstance(value, tuple):
        return ",".join(map(show_value, value)) if value else "''"
    return repr(value) if isinstance(value, str) else str(value)


def field_problem(path: str, value, ranges: dict[str, Range] | None = None) -> str | None:
    """The one-line message if `value` is outside the range of the field at `path`, or None."""
    problem = (ranges or field_ranges())[path].problem(value)
    if problem is None:
        return None
    return f"{flag_name(path)} must be {problem}, got {show_value(value)}"


def cross_field_problem(cfg: TrainConfig) -> str | None:
    """The one-line message of the first violated constraint between fields, or None."""
    cur, sac, clf = cfg.curriculum, cfg.sac, cfg.classifier
    problem = _algo_problem(cfg)
    if problem:
        return problem
    if clf.marginal_group > clf.batch_size:
        return (
            f"--classifier.marginal-group must be <= --classifier.batch-size "
            f"({clf.batch_size}; each group shares one goal of the batch), got {clf.marginal_group}"
        )
    if cur.pool_size < cur.n_slots:
        return (
            f"--curriculum.pool-size must be >= --curriculum.n-slots ({cur.n_slots}; "
            f"K <= P, SPEC §5), got {cur.pool_size}"
        )
    if not sac.log_std_min < sac.log_std_max:
        return (
            f"--sac.log-std-min must be < --sac.log-std-max ({sac.log_std_max}), "
            f"got {sac.log_std_min}"
        )
    if cfg.seed + cfg.num_seeds - 1 > _MAX_SEED:
        return (
            f"--seeds must be <= {_MAX_SEED - cfg.seed + 1} with --seed {cfg.seed} "
            f"(the last seed must be <= {_MAX_SEED}), got {cfg.num_seeds}"
        )
    # The buffer holds capacity // H episode slots; each iteration stores num_envs
    # episodes and the curriculum pool reads the pool_size most recent ones.
    import envs  # here: the command line imports this module before it needs jax

    horizon = envs.horizon(cfg.env) if cfg.env in envs.ENV_NAMES else None
    episodes = max(cfg.num_envs, cur.pool_size)
    if horizon is not None and cfg.replay.capacity < episodes * horizon:
        return (
            f"--replay.capacity must be >= {episodes * horizon} (max(--num-envs, "
            f"--curriculum.pool-size) = {episodes} episodes of {horizon} steps), "
            f"got {cfg.replay.capacity}"
        )
    # The archive draws distinct episodes from the buffer's capacity // H slots.
    if horizon is not None and cur.archive_size > cfg.replay.capacity // horizon:
        return (
            f"--curriculum.archive-size must be <= {cfg.replay.capacity // horizon} (the "
            f"buffer's episode slots: --replay.capacity {cfg.replay.capacity} // {horizon} "
            f"steps), got {cur.archive_size}"
        )
    # The two relabelling coins share one batch: future, random, own goal.
    if cfg.her.relabel_prob + cfg.her.random_prob > 1 + 1e-9:  # 0.8 + 0.2 in floats
        return (
            "--her.relabel-prob + --her.random-prob must be <= 1, got "
            f"{cfg.her.relabel_prob} + {cfg.her.random_prob}"
        )
    # Walk steps are kept only where the pool is cut at the success step.
    if cur.pool_walk_steps > 0 and cur.pool_phase != "curriculum_phase":
        return (
            "--curriculum.pool-walk-steps must be 0 unless --curriculum.pool-phase is "
            f"curriculum_phase (it is {cur.pool_phase}), got {cur.pool_walk_steps}"
        )
    return None


def _algo_problem(cfg: TrainConfig) -> str | None:
    """A D2C-only setting (or another reward) given to an algorithm that fixes it."""
    if cfg.algo == "d2c":
        return None
    fixed = ALGO_REWARDS[cfg.algo]
    if fixed is not None and cfg.reward != fixed:
        return (
            f"--reward {cfg.reward} conflicts with --algo {cfg.algo}, which trains with the "
            f"{fixed} reward (paper appendix A.1)"
        )
    if cfg.algo == "outpace" and cfg.sac.clip_target:
        # The clip is [0, 1/(1 - gamma)], the return range of rewards in [0, 1]; OUTPACE's
        # AIM reward is negative, so every target would clip to 0.
        return (
            "--sac.clip-target conflicts with --algo outpace: it clips targets to "
            "[0, 1/(1 - gamma)], and OUTPACE's AIM reward is negative"
        )
    if cfg.curriculum.variant != "d2c":
        return (
            f"--curriculum.variant {cfg.curriculum.variant} is a D2C ablation; it conflicts "
            f"with --algo {cfg.algo}, which has its own curriculum"
        )
    if cfg.curriculum.goal_value_weight != 0:
        return (
            f"--curriculum.goal-value-weight {cfg.curriculum.goal_value_weight} weights D2C's "
            f"matching; it conflicts with --algo {cfg.algo}, which has its own curriculum"
        )
    return None
