"""Sweeps (issue 13): hyperparameter arms x seeds as one run axis of one program.

`TrainConfig.sweep` holds (dotted field, values) pairs. Their Cartesian product (the last
pair varying fastest) gives the arms; every arm runs seeds S..S+N-1 (`--seed S --seeds
N`). Run r of the run axis is arm r // N with seed S + r % N, so arm a with seed s is
the single run with that arm's values and seed s: the swept values are traced leaves of
the state (`agent.Hyperparams`), not constants of the program, and everything else is
shared. Only fields that keep every shape and static count can be swept
(`SWEEPABLE_FIELDS`); sizes, counts and cadences change the program itself.

This module is plain Python (no jax): the command line checks sweeps before JAX loads.
"""

from __future__ import annotations

import dataclasses
import itertools

from d2c_jax import config as config_lib
from d2c_jax import config_io

# The fields the step reads from `TrainState.hparams` (`agent.hyperparams` builds them
# from a config), by dotted path. `tests/test_sweep.py` checks that each one reaches the
# hyperparameters and that a sweep arm equals the single run.
SWEEPABLE_FIELDS: tuple[str, ...] = (
    "sac.actor_lr",
    "sac.critic_lr",
    "sac.alpha_lr",
    "sac.tau",
    "sac.init_alpha",
    "classifier.lr",
    "classifier.diversity_weight",
    "classifier.marginal_weight",
    "classifier.marginal_prior",
    "classifier.eps",
    "her.relabel_prob",
    "curriculum.goal_noise",
    "curriculum.goal_value_weight",
    "curriculum.post_success_range",
    "curriculum.post_success_threshold",
    "curriculum.post_success_relax",
    "curriculum.post_success_temperature",
    "reward",
)


def flag_spelling(field: str) -> str:
    """A dotted field as the flags spell it: 'classifier.diversity_weight' ->
    'classifier.diversity-weight'."""
    return field.replace("_", "-")


def sweepable_list() -> str:
    """The sweepable fields as flags spell them, comma-separated (for messages)."""
    return ", ".join(flag_spelling(f) for f in SWEEPABLE_FIELDS)


def n_arms(cfg: config_lib.TrainConfig) -> int:
    """Arms of the sweep: the product of its value lists' lengths (1 without a sweep)."""
    count = 1
    for _, values in cfg.sweep:
        count *= len(values)
    return count


def n_runs(cfg: config_lib.TrainConfig) -> int:
    """Runs of the run axis: arms x seeds."""
    return n_arms(cfg) * cfg.num_seeds


def arm_values(cfg: config_lib.TrainConfig) -> list[tuple]:
    """Each arm's values, one per swept field, in run-axis order (last field fastest)."""
    return list(itertools.product(*(values for _, values in cfg.sweep)))


def arm_configs(cfg: config_lib.TrainConfig) -> list[config_lib.TrainConfig]:
    """The config of every arm: `cfg` with that arm's values and no sweep."""
    fields = [field for field, _ in cfg.sweep]
    arms = []
    for values in arm_values(cfg):
        arm = dataclasses.replace(cfg, sweep=())
        for field, value in zip(fields, values, strict=True):
            arm = config_io.replace_field(arm, field, value)
        arms.append(arm)
    return arms


def run_configs(cfg: config_lib.TrainConfig) -> list[config_lib.TrainConfig]:
    """The config of every run r = arm * N + (seed - S): its arm's, with its one seed."""
    return [
        dataclasses.replace(arm, seed=cfg.seed + i, num_seeds=1)
        for arm in arm_configs(cfg)
        for i in range(cfg.num_seeds)
    ]


def run_seeds(cfg: config_lib.TrainConfig) -> list[int]:
    """The seed of every run, in run-axis order."""
    return [cfg.seed + r % cfg.num_seeds for r in range(n_runs(cfg))]


def problem(cfg: config_lib.TrainConfig) -> str | None:
    """One line describing what is wrong with `cfg.sweep`, or None.

    Each field must be sweepable and appear once, each value list non-empty, and every
    arm's config valid (the caller validates it with the same rules as a single run).
    """
    seen = set()
    for field, values in cfg.sweep:
        if field not in SWEEPABLE_FIELDS:
            return (
                f"--sweep {flag_spelling(field)}: not a sweepable field (it changes shapes or "
                f"static counts, or is not a hyperparameter); sweepable: {sweepable_list()}"
            )
        if field in seen:
            return f"--sweep {flag_spelling(field)} is given twice; give all its values once"
        seen.add(field)
        if not values:
            return f"--sweep {flag_spelling(field)} needs at least one value"
    return None
