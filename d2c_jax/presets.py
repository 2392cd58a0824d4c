"""The presets `paper`, `quick` and `tiny` per env, and `with_algo` (SPEC §2, §8 Table 3).

A preset is a function of the env id that returns a frozen `TrainConfig`
(`d2c_jax.config`, which also re-exports these names, so `config.preset(...)` works).
`paper` is Tables 2-3; `quick` learns on a 2-core CPU, and every departure from the
paper in it is listed in docs/DEVIATIONS.md with the runs that decided it.
"""

from __future__ import annotations

import dataclasses

from d2c_jax.config import (
    ALGO_NAMES,
    ALGO_REWARDS,
    TEACHER_ALGOS,
    ClassifierConfig,
    CurriculumConfig,
    ReplayConfig,
    TrainConfig,
    env_settings,
    iteration_steps,
)

PRESET_NAMES = ("paper", "quick", "tiny")


def paper_preset(env: str) -> TrainConfig:
    """Tables 2-3: 3x512 SAC, batch 512, utd 1, K = 20 slots; num_envs = 20 (SPEC §2) except
    on Ant (`_PAPER_OVERRIDES`)."""
    return _replace_nested(_table_settings(env), _PAPER_OVERRIDES.get(env, {}))


# Ant's paper preset collects one episode per iteration, as the authors' sequential loop
# does, and matches its K = 20 slots every 20 episodes (each iteration takes the next slot):
# new data every 300 SAC updates instead of 6,000. With 20 envs its 3x512 critic diverges
# (Q 111 at 12k env steps, 474 at 18k, 1,872 at 24k against a bound of about 100; 4 envs:
# 94 and 131; 1 env: 62 and 67), on a CPU as on a GPU (benchmarks/RESULTS.md,
# "updates per data refresh"; docs/DEVIATIONS.md). Checkpoints stay every 150k env steps.
_PAPER_OVERRIDES: dict[str, dict] = {
    "ant": dict(num_envs=1, curriculum=dict(rematch_every=20 * 300)),
}


def _table_settings(env: str) -> TrainConfig:
    """SPEC §2 and Tables 2-3 exactly, the base of every preset: 3x512 SAC, batch 512,
    utd 1, num_envs = n_slots = 20."""
    s = env_settings(env)
    return TrainConfig(
        env=env,
        preset="paper",
        total_steps=s.total_steps,
        seed_steps=s.seed_steps,
        checkpoint_every=iteration_steps(env, TrainConfig.num_envs, 25),
        classifier=ClassifierConfig(
            n_heads=s.n_heads,
            diversity_weight=s.diversity_weight,
            eps=s.eps,
            update_every=s.classifier_every,
        ),
        curriculum=CurriculumConfig(post_success_range=s.post_success_range, goal_noise=s.eps),
    )


def quick_preset(env: str) -> TrainConfig:
    """Tuned to learn fast on a laptop CPU (see docs/DEVIATIONS.md, "quick preset")."""
    cfg = _table_settings(env)
    num_envs = 20
    quick = dataclasses.replace(
        cfg,
        preset="quick",
        num_envs=num_envs,
        utd=0.25,
        eval_every=10_000,
        checkpoint_every=iteration_steps(env, num_envs, 50),
        sac=dataclasses.replace(cfg.sac, hidden_sizes=(256, 256), batch_size=256),
        replay=ReplayConfig(capacity=1_000_000),
        classifier=dataclasses.replace(cfg.classifier, hidden_sizes=(128, 128), batch_size=256),
    )
    if env in _TRAP_ENVS:
        quick = with_outpace_exploration(quick)
    return _replace_nested(quick, _QUICK_OVERRIDES.get(env, {}))


def _replace_nested(cfg, overrides: dict):
    """`cfg` with `overrides` applied; a dict value overrides fields of that sub-config."""
    values = {
        name: _replace_nested(getattr(cfg, name), value) if isinstance(value, dict) else value
        for name, value in overrides.items()
    }
    return dataclasses.replace(cfg, **values)


# Envs whose desired outcomes lie behind a wall from the start, so that the Euclidean-
# nearest reachable states are traps for D2C as SPEC §3-§6 write it (issue 10): their
# quick preset adds OUTPACE's exploration options (docs/DEVIATIONS.md, "Exploration
# options"). Only medium_maze, whose corridors lead straight to every mode, keeps SPEC.
_TRAP_ENVS = ("complex_maze", "spiral_maze", "ant", "sawyer_push", "sawyer_pick_place")

# Per env, the quick preset's other departures from the settings above:
# - the two trap mazes: the paper's one SAC update per env step (run U of RESULTS.md, the
#   only configuration measured to learn complex_maze);
# - complex_maze also SPEC §3's classifier size, 3x256 with batch 512 (run V: eval >= 0.8
#   at 820k env steps with seed 0 and 590k with seed 7, against U's 1.01M and 600k);
# - spiral_maze also the critic's value as a tie-break in the matching (beta = 1, run F:
#   0.5 from 1.67M env steps, 1.0 at 2.11M; U stayed at 0.0, its slots collapsing onto one
#   corridor), SPEC §3's classifier size as complex_maze, and SAC learning rates of 3e-4
#   (run LV: eval >= 0.8 first at 860k env steps with seed 0, 1.0 from 940k; with seed 7
#   first at 1.92M), and since 2026-12-04 two SAC updates per env step (LV at utd 2: eval
#   >= 0.8 first at 940k with seed 1, where LV at utd 1 had only the top mode by 2M, and
#   at 810k with seed 0, where utd 1 took 860k);
# - Ant and Sawyer: an evaluation every 30k env steps instead of 10k; an evaluation runs
#   as many env steps as a training iteration (20 or 30 episodes of the horizon): every
#   10k env steps 11-14% of the train step's time, every 30k 4-5% (`benchmarks.profile`).
# - sawyer_push also SAC learning rates of 3e-4 instead of Table 2's 1e-4 and, since
#   2026-12-04, Table 2's one SAC update per env step: with both, mode 2 (the one on the
#   start's side of the wall) is evaluated at 0.8 first at 992k env steps with seed 0
#   (0.64 on average from 1.6M) where utd 0.25 reaches it at 2.75M-2.91M (0.08 on
#   average), and seed 1 at 0.8 first at 960k (0.0 to 2.25M at utd 0.25); neither alone
#   did as much (utd 1 at 1e-4: eval 0.0 to 1M). About 2.2x the minutes per env step.
# - ant, since 2026-12-06: the paper's utd 1 with SAC learning rates of 3e-4, the clipped
#   target, SPEC §3's classifier size, HER's future goals at least one radius away, the
#   matching pool cut 50 walk steps after each episode's success, and 10-step returns:
#   the only configuration measured to reach a mode (the run with all but the last was at
#   eval 0.0 to 3M; with 10-step returns from its 2.7M checkpoint, mode 0 at 0.8 30k env
#   steps later and 1.0 at 3M). About 57 s per 6000-step iteration here (8 hours per 3M).
#   Since 2026-12-07 also the critic's value as a tie-break in the matching (beta = 1, as
#   spiral_maze): from scratch with seed 0, mode 1 at 0.7-1.0 from 2,160k env steps and
#   eval/success 1.0 (both modes) first at 2,730k, where the preset without it was at 0.0
#   to 1,506k with its slots on one arm.
# - sawyer_push also 10-step returns since 2026-12-06: from scratch with seed 0, mode 1
#   (behind the wall) at 0.7-1.0 from 320k env steps and mode 2 at 1.0 from 160k, where
#   the same preset without them had mode 2 first at 416k and mode 0 or 1 at no
#   evaluation to 988k; eval/success >= 0.8 first at 640k and 0.87-1.0 from 704k to 804k.
# - sawyer_pick_place, since 2026-12-06, push's settings (utd 1, SAC learning rates of
#   3e-4, 10-step returns): with seed 0, eval/success 1.0 first at 384k env steps and
#   0.9-1.0 to 484k, where every earlier pick & place run (utd 0.25 or 1, learning rates
#   1e-4 or 3e-4, one-step targets; to 0.66-1.78M) was at eval 0.0 throughout.
_SPEC_CLASSIFIER_SIZE = dict(
    hidden_sizes=ClassifierConfig.hidden_sizes, batch_size=ClassifierConfig.batch_size
)  # SPEC §3's trunk and batch, which the common quick settings shrink to 2x128 and 256
_SAC_LR_3E4 = dict(actor_lr=3e-4, critic_lr=3e-4, alpha_lr=3e-4)
_SAWYER_QUICK = dict(eval_every=30_000, utd=1.0, sac=_SAC_LR_3E4, her=dict(n_step=10))
_QUICK_OVERRIDES: dict[str, dict] = {
    "complex_maze": dict(utd=1.0, classifier=_SPEC_CLASSIFIER_SIZE),
    "spiral_maze": dict(
        utd=2.0,
        curriculum=dict(goal_value_weight=1.0),
        classifier=_SPEC_CLASSIFIER_SIZE,
        sac=_SAC_LR_3E4,
    ),
    "ant": dict(
        eval_every=30_000,
        utd=1.0,
        sac=dict(**_SAC_LR_3E4, clip_target=True),
        classifier=_SPEC_CLASSIFIER_SIZE,
        her=dict(min_future_radii=1.0, n_step=10),
        curriculum=dict(pool_phase="curriculum_phase", pool_walk_steps=50, goal_value_weight=1.0),
    ),
    "sawyer_push": _SAWYER_QUICK,
    "sawyer_pick_place": _SAWYER_QUICK,
}


def with_outpace_exploration(cfg: TrainConfig) -> TrainConfig:
    """`cfg` with issue 10's exploration options on (variant A of benchmarks/RESULTS.md):
    OUTPACE's post-success random walk and random-walk buffer, negatives from the
    curriculum phase, a 400-episode archive in the matching pool, pool candidates from
    trajectory tails (episodes that moved at least 0.08 r), and the marginal term (mu = 1,
    prior 0.3)."""
    return dataclasses.replace(
        cfg,
        replay=dataclasses.replace(cfg.replay, walk_fraction=0.2),
        classifier=dataclasses.replace(
            cfg.classifier,
            marginal_weight=1.0,
            marginal_prior=0.3,
            negatives="curriculum_phase",
        ),
        curriculum=dataclasses.replace(
            cfg.curriculum,
            post_success_rule="outpace",
            post_success_candidates=10,
            post_success_switch_every=10,
            archive_size=400,
            pool_tail_fraction=0.5,
            # OUTPACE's 0.2 maze units, scaled by Table 3's r (2.5 on the mazes and Ant):
            # on Sawyer's table (r = 0.1 m) an absolute 0.2 m would leave most episodes out.
            pool_min_move=_MIN_MOVE_PER_R * cfg.curriculum.post_success_range,
        ),
    )


# OUTPACE's minimum move (0.2 maze units) per unit of Table 3's post-success range r.
_MIN_MOVE_PER_R = 0.2 / 2.5


def tiny_preset(env: str) -> TrainConfig:
    """Seconds per run, for tests: tiny nets, few envs, 2 iterations."""
    cfg, num_envs = _table_settings(env), 4
    return dataclasses.replace(
        cfg,
        preset="tiny",
        total_steps=iteration_steps(env, num_envs, 2),
        num_envs=num_envs,
        utd=0.02,
        seed_steps=1,
        eval_every=1,
        eval_episodes=2,
        checkpoint_every=iteration_steps(env, num_envs, 1),
        sac=dataclasses.replace(cfg.sac, hidden_sizes=(32, 32), batch_size=32),
        replay=ReplayConfig(capacity=20_000),
        classifier=dataclasses.replace(
            cfg.classifier, hidden_sizes=(32, 32), batch_size=32, iters=2, update_every=100
        ),
        curriculum=dataclasses.replace(cfg.curriculum, n_slots=4, pool_size=4),
    )


def preset(env: str, name: str) -> TrainConfig:
    """The preset `name` (paper | quick | tiny) for env `env`.

    Raises:
      ValueError: for an unknown preset or env.
    """
    env_settings(env)  # raises for an unknown env, before an unknown preset
    builders = {"paper": paper_preset, "quick": quick_preset, "tiny": tiny_preset}
    if name not in builders:
        raise ValueError(f"unknown preset {name!r}; valid presets: {', '.join(PRESET_NAMES)}")
    return builders[name](env)


def with_algo(cfg: TrainConfig, algo: str) -> TrainConfig:
    """`cfg` trained by `algo` (`ALGO_NAMES`), on the preset's SAC, HER and pool.

    HER and HGG get the sparse reward (`ALGO_REWARDS`) and none of D2C's own options: no
    random-walk buffer (they never switch goals after success, so it would stay empty)
    and no beta value term in a matching they do not use. OUTPACE gets its own
    exploration settings and per-env constants (`_outpace_settings`).

    Raises:
      ValueError: for an unknown algo.
    """
    if algo not in ALGO_NAMES:
        raise ValueError(f"--algo must be one of {', '.join(ALGO_NAMES)}, got {algo!r}")
    if algo == "d2c":
        return dataclasses.replace(cfg, algo=algo)
    if algo == "outpace":
        return _outpace_settings(dataclasses.replace(cfg, algo=algo, reward="intrinsic"))
    curriculum = dataclasses.replace(cfg.curriculum, goal_value_weight=0.0)
    if algo in TEACHER_ALGOS:  # one goal per episode, proposed every iteration
        curriculum = dataclasses.replace(
            curriculum,
            n_slots=cfg.num_envs,
            pool_size=max(cfg.num_envs, curriculum.pool_size),
            rematch_every=iteration_steps(cfg.env, cfg.num_envs, 1),
        )
    sizes = _TEACHER_PRESET_SIZES.get(algo, {}).get(cfg.preset, {})
    return dataclasses.replace(
        cfg,
        algo=algo,
        reward=ALGO_REWARDS[algo],
        replay=dataclasses.replace(cfg.replay, walk_fraction=0.0),
        curriculum=curriculum,
        teachers=dataclasses.replace(cfg.teachers, **sizes),
    )


# Teacher sizes per algo and preset; `paper` keeps the reference's. VDS: its 800 TD
# updates of 5 members per 10k env steps are about 4x the SAC update's cost at the quick
# preset's sizes on a CPU. CURROT: `tiny` only shrinks it for tests.
_TEACHER_PRESET_SIZES: dict[str, dict[str, dict]] = {
    "vds": {
        "quick": dict(vds_updates_per_10k=200, vds_batch_size=256),
        "tiny": dict(vds_members=3, vds_hidden_sizes=(16,), vds_batch_size=32, vds_candidates=64),
    },  # fmt: skip
    "currot": {
        "tiny": dict(currot_particles=16, currot_episodes_per_update=4, currot_candidates=8),
    },
}


def _outpace_settings(cfg: TrainConfig) -> TrainConfig:
    """OUTPACE's own settings on top of `cfg` (outpace_official outpace_train.py's per-env
    dicts and the README's flags; docs/BASELINES.md): its random walk and random-walk
    buffer, a pool of the last 100 trajectories that moved (0.2 maze units, 0.02 m on
    Sawyer), their last 50% every 4th state (6th on Ant), and the per-env constants."""
    sawyer = cfg.env.startswith("sawyer")
    with_walk = with_outpace_exploration(cfg)
    curriculum = dataclasses.replace(
        with_walk.curriculum,
        archive_size=0,
        goal_value_weight=0.0,
        pool_min_move=0.02 if sawyer else 0.2,
        cost_stride=6 if cfg.env == "ant" else 4,
    )
    outpace = cfg.outpace
    if sawyer:
        outpace = dataclasses.replace(
            outpace,
            nml_input_scale=1 / 0.05,
            aim_target_noise=0.01,
            goal_noise_std=0.05,
            cost_lipschitz=0.5 if cfg.env == "sawyer_push" else outpace.cost_lipschitz,
        )
    if cfg.env == "spiral_maze":
        outpace = dataclasses.replace(outpace, aim_penalty=50.0)
    outpace = dataclasses.replace(outpace, **_OUTPACE_PRESET_SIZES.get(cfg.preset, {}))
    return dataclasses.replace(with_walk, curriculum=curriculum, outpace=outpace)


# OUTPACE's sizes per preset; `paper` keeps the authors' 2x2048 meta-NML network. Meta-NML
# adapts a copy of the network for every query, and OUTPACE's random walk queries 10
# candidates per env at every goal switch (about every step with 20 envs): at 2x2048 that
# is hours per iteration on a CPU, so `quick` uses 2x64 and fewer meta-test points
# (docs/BASELINES.md).
_OUTPACE_PRESET_SIZES: dict[str, dict] = {
    "quick": dict(nml_hidden_sizes=(64, 64), nml_train_points=256, nml_test_points=512),
    "tiny": dict(
        nml_hidden_sizes=(16, 16), nml_train_points=32, nml_test_points=64,
        nml_context_points=7, nml_tasks_per_step=4, nml_steps_per_round=2,
        aim_members=2, aim_hidden_sizes=(16, 16), aim_batch_size=32,
    ),
}  # fmt: skip
