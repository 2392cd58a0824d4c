"""Every environment trains: the tiny preset's train and eval steps on each env id.

A new env, or a trainer change that breaks one env (as `env.start_goal` traced inside the
step once broke Sawyer), fails here rather than in a user's run.
"""

import numpy as np
import pytest

import envs
from d2c_jax.training import agent as agent_lib
from d2c_jax.training import cli, loop


@pytest.mark.parametrize("env_name", envs.ENV_NAMES)
def test_tiny_preset_trains_and_evaluates(env_name, tmp_path, undocumented_metrics):
    cfg, _, _ = cli.parse_args(["--env", env_name, "--preset", "tiny"])
    out = tmp_path / "run"
    assert loop.train(cfg, out, quiet=True) == 0
    from d2c_jax.training import logging as logging_lib

    rows = logging_lib.read_metrics(out / "metrics.jsonl")
    assert [r["iteration"] for r in rows] == [1, 2]
    assert not undocumented_metrics(rows)  # every key it writes is in docs/METRICS.md
    last = rows[-1]
    env = envs.make(env_name)
    assert all(f"eval/success/{k}" in last for k in range(env.n_modes))
    for key in ("eval/success", "curriculum/distance", "sac/critic_loss", "classifier/loss"):
        assert np.isfinite(last[key]), key
    assert (out / "plots" / "curriculum.png").exists()


_FAMILY_ENVS = ["medium_maze"] + [
    pytest.param(e, marks=pytest.mark.slow) for e in ("ant", "sawyer_pick_place")
]


@pytest.mark.parametrize("env_name", _FAMILY_ENVS)
@pytest.mark.parametrize(
    "args, fields",
    [
        (["--sac.relative-goal", "true"], [("sac", "relative_goal", True)]),
        (
            ["--curriculum.pool-phase", "curriculum_phase", "--curriculum.pool-walk-steps", "5"],
            [
                ("curriculum", "pool_phase", "curriculum_phase"),
                ("curriculum", "pool_walk_steps", 5),
            ],
        ),
        (["--sac.actor-mean-reg", "0.01"], [("sac", "actor_mean_reg", 0.01)]),
        (
            ["--her.relabel-prob", "0.5", "--her.random-prob", "0.3"],
            [("her", "relabel_prob", 0.5), ("her", "random_prob", 0.3)],
        ),
        (["--her.n-step", "4"], [("her", "n_step", 4)]),
    ],
    ids=["relative_goal", "pool_phase", "actor_mean_reg", "her_random", "n_step"],
)
def test_default_off_options_train_on_each_family(env_name, args, fields, tmp_path):
    """The default-off options through the CLI, one env per family:
    `--sac.relative-goal true` (each family reads phi back from its obs with its own
    `goal_of_obs`, which the env tests check against `achieved_goal`) and
    `--curriculum.pool-phase curriculum_phase` (matching candidates held at each pool
    episode's success state, here 5 walk steps after it) and `--sac.actor-mean-reg`
    (the pre-tanh mean's penalty in J_pi) and `--her.random-prob` (HER's "random" goals
    from the whole buffer) and `--her.n-step` (n-step returns). The Ant and Sawyer runs compile
    their MJX programs anew (1-2 min each on 2 cores), so they are slow tests."""
    from d2c_jax.training import logging as logging_lib

    cfg, _, _ = cli.parse_args(["--env", env_name, "--preset", "tiny", *args])
    for section, name, expected in fields:
        assert getattr(getattr(cfg, section), name) == expected
    out = tmp_path / "run"
    assert loop.train(cfg, out, quiet=True) == 0
    last = logging_lib.read_metrics(out / "metrics.jsonl")[-1]
    for key in ("eval/success", "sac/critic_loss", "sac/q_mean", "curriculum/distance"):
        assert np.isfinite(last[key]), key


def _goal_spread(row: dict, start_goal: np.ndarray) -> float:
    """Mean distance of a row's curriculum goals (K, d) from the start goal."""
    goals = np.asarray(row["curriculum/goals"], np.float64).reshape(-1, start_goal.shape[-1])
    return float(np.linalg.norm(goals - start_goal, axis=-1).mean())


# One env per family and the env steps its quick preset needs to move the goals (seed 0,
# measured on the issue-15 learning runs: Ant's goals are 3.7 from the start at 156k,
# Sawyer push's 0.19 at 300k, that run with the older 0.2 m minimum pool move; the push
# preset at one update per env step passes at 320k too, in 26 minutes beside a training
# run on 2 cores, 2026-12-04).
_FAMILIES = [("medium_maze", 40_000), ("ant", 200_000), ("sawyer_push", 320_000)]


@pytest.mark.slow
@pytest.mark.parametrize("env_name, total_steps", _FAMILIES)
def test_quick_preset_moves_the_curriculum_away_from_the_start(env_name, total_steps, tmp_path):
    """A short quick-preset run (seed 0) takes the curriculum goals away from the start.

    After the warm-up the matched goals begin at the start (where the pool's states are).
    They must end at least twice as far from it. On the maze the paper-style
    `curriculum/distance` must also end at least 20% below its first value; on Ant's
    U-shaped maze and behind Sawyer's wall the goals first move along the way round,
    which is no nearer the desired outcomes in straight-line distance, so there the
    paper's metric only falls late in a run (benchmarks/RESULTS.md).
    """
    from d2c_jax.training import logging as logging_lib

    cfg, _, _ = cli.parse_args(
        ["--env", env_name, "--preset", "quick", "--total-steps", str(total_steps)]
    )
    out = tmp_path / "run"
    assert loop.train(cfg, out, quiet=True) == 0
    env = envs.make(env_name)
    warmup = agent_lib.make_schedule(cfg, env.horizon).warmup_iterations
    rows = [r for r in logging_lib.read_metrics(out / "metrics.jsonl") if r["iteration"] > warmup]
    with_goals = [r for r in rows if "curriculum/goals" in r]
    start = np.asarray(env.start_goal, np.float64)
    first, last = _goal_spread(with_goals[0], start), _goal_spread(with_goals[-1], start)
    assert last >= 2 * first, (first, last)
    if env_name == "medium_maze":
        first_distance = rows[0]["curriculum/distance"]
        end_distance = np.mean([r["curriculum/distance"] for r in rows[-3:]])
        assert end_distance <= 0.8 * first_distance, (first_distance, end_distance)
