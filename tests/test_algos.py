"""The curriculum interface and the baselines on it (`--algo d2c|her|hgg`, issue 18)."""

import dataclasses
import json
import os
import pathlib
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.optimize

import envs
from d2c_jax import config, config_io
from d2c_jax.curricula import curriculum, hgg, interface
from d2c_jax.training import agent as agent_lib
from d2c_jax.training import cli, loop, validation
from d2c_jax.training import logging as logging_lib


def run_cli(*args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "JAX_PLATFORMS": "cpu"}
    root = pathlib.Path(__file__).resolve().parents[1]
    cmd = [sys.executable, "train.py", *args]
    return subprocess.run(cmd, capture_output=True, text=True, cwd=root, timeout=600, env=env)


def strip_time(rows: list[dict]) -> list[dict]:
    return [{k: v for k, v in r.items() if not k.startswith("time/")} for r in rows]


BASELINES = ("her", "hgg")
# The algos trained once here in the default suite; their resume tests are slow (the
# curriculum state's checkpointing is tested once, on a probe curriculum, below).
_TRAINED_ONCE_HERE = ("her", "hgg", "outpace") + config.TEACHER_ALGOS


def _train_tiny(env_name: str, algo: str, out, *extra: str) -> list[dict]:
    cfg, _, _ = cli.parse_args(["--env", env_name, "--preset", "tiny", "--algo", algo, *extra])
    assert loop.train(cfg, out, quiet=True) == 0
    return logging_lib.read_metrics(out / "metrics.jsonl")


def _check_baseline_run(env_name: str, algo: str, out, undocumented=None) -> None:
    rows = _train_tiny(env_name, algo, out)
    if undocumented is not None:  # every key it writes is in docs/METRICS.md
        assert not undocumented(rows)
    assert [r["iteration"] for r in rows] == [1, 2]
    last = rows[-1]
    for key in ("eval/success", "curriculum/distance", "sac/critic_loss"):
        assert np.isfinite(last[key]), key
    # The sparse reward is 0 or 1 per transition, and no classifier is trained.
    if config.ALGO_REWARDS[algo] == "sparse":
        assert 0.0 <= last["sac/reward_mean"] <= 1.0
    assert not any(k.startswith("classifier/") for k in last)
    assert config_io.from_dict(config.TrainConfig, _config_json(out)).algo == algo


def _config_json(out) -> dict:
    return json.loads((out / "config.json").read_text())


@pytest.mark.parametrize("algo", _TRAINED_ONCE_HERE)
def test_baseline_trains_tiny_on_medium_maze(algo, tmp_path, undocumented_metrics, capsys):
    _check_baseline_run("medium_maze", algo, tmp_path / "run", undocumented_metrics)
    if algo == "her":  # a probe that re-runs D2C's matching refuses a run without one
        from benchmarks import visit_map

        capsys.readouterr()
        assert visit_map.main([str(tmp_path / "run"), "--rematch", "1"]) == 2
        first = capsys.readouterr().err.splitlines()[0]
        assert first.startswith("error: --rematch needs a D2C run") and "--algo her" in first
        # The actor probe's route mode on a real run: waypoints one radius apart are refused.
        from benchmarks import actor_probe

        route = ["--route", "--episodes", "1", "--", "4,0;4,0.5"]
        assert actor_probe.main([str(tmp_path / "run"), *route]) == 2
        first = capsys.readouterr().err.splitlines()[0]
        assert first.startswith("error: route waypoints must lie more than 2 success radii")
        route[-1] = "4,0;8,0"
        assert actor_probe.main([str(tmp_path / "run"), *route]) == 0
        out = capsys.readouterr().out.splitlines()
        assert out[1].startswith("waypoint") and [line.split()[0] for line in out[2:]] == [
            "4,0", "8,0"
        ]  # fmt: skip


@pytest.mark.slow
@pytest.mark.parametrize("algo", BASELINES)
@pytest.mark.parametrize("env_name", [e for e in envs.ENV_NAMES if e != "medium_maze"])
def test_baseline_trains_tiny_on_every_env(env_name, algo, tmp_path):
    _check_baseline_run(env_name, algo, tmp_path / "run")


# --- the rule: an algo that fixes the reward refuses any other ------------------------


@pytest.mark.parametrize("algo", config.ALGO_NAMES)
@pytest.mark.parametrize("reward", ["intrinsic", "sparse"])
def test_an_algo_that_fixes_the_reward_refuses_another(algo, reward):
    cfg = dataclasses.replace(
        config.with_algo(config.preset("medium_maze", "tiny"), algo), reward=reward
    )
    problem = validation.validate(cfg)
    fixed = config.ALGO_REWARDS[algo]
    if fixed is None or fixed == reward:
        assert problem is None
    else:
        assert problem.startswith(f"--reward {reward} conflicts with --algo {algo}"), problem


_CONFLICTS = [
    (["--algo", "hgg", "--reward", "intrinsic"], "--reward intrinsic conflicts with --algo hgg"),
    (["--algo", "her", "--curriculum.variant", "value"], "--curriculum.variant value is a D2C"),
    (
        ["--algo", "hgg", "--curriculum.goal-value-weight", "1"],
        "--curriculum.goal-value-weight 1.0",
    ),
    (
        ["--algo", "outpace", "--sac.clip-target", "true"],
        "--sac.clip-target conflicts with --algo outpace",
    ),
    (["--algo", "ppo"], f"--algo must be one of {', '.join(config.ALGO_NAMES)}, got 'ppo'"),
]


@pytest.mark.parametrize("args, first_line", _CONFLICTS)
def test_conflicting_or_unknown_algo_exits_2(args, first_line, tmp_path):
    result = run_cli(
        "--env", "medium_maze", "--preset", "tiny", *args, "--out", str(tmp_path / "r")
    )
    assert result.returncode == 2, result.stderr
    assert result.stderr.splitlines()[0].startswith("error: " + first_line), result.stderr
    assert "Traceback" not in result.stderr


# --- what each curriculum does -------------------------------------------------------


@pytest.fixture(scope="module")
def maze():
    return envs.make("medium_maze")


@pytest.mark.slow  # the default suite's tiny baseline runs check the same through loop.train
def test_baselines_train_no_classifier_and_use_the_sparse_reward(maze):
    cfg = config.with_algo(config.preset("medium_maze", "tiny"), "her")
    agent = agent_lib.Agent(cfg, maze)
    assert agent.schedule.classifier_updates == 0 and agent.rewards == ("sparse",)
    ts = agent.init(jax.random.key(0))
    ts2, _ = jax.jit(agent.step)(ts)
    ts2, _ = jax.jit(agent.step)(ts2)
    same = jax.tree.map(np.array_equal, ts.classifier.params, ts2.classifier.params)
    assert all(jax.tree.leaves(same))
    # The goals of HER are draws of the desired examples: slot j near mode j mod n_modes.
    modes = np.asarray(maze.goal_points)
    goals = np.asarray(ts2.curriculum_goals)
    nearest = np.linalg.norm(goals[:, None] - modes[None], axis=-1).argmin(axis=1)
    assert list(nearest) == [j % len(modes) for j in range(len(goals))]


def test_d2c_and_its_ablations_keep_their_curricula():
    tiny = config.preset("medium_maze", "tiny")
    none = dataclasses.replace(
        tiny, curriculum=dataclasses.replace(tiny.curriculum, variant="none")
    )
    assert interface.curriculum_class(tiny) is interface.MatchingCurriculum
    assert interface.curriculum_class(none) is interface.NoCurriculumAblation
    assert interface.curriculum_class(config.with_algo(tiny, "hgg")) is hgg.HGGCurriculum
    assert interface.train_reward(dataclasses.replace(tiny, reward="sparse")) == "sparse"
    assert interface.train_reward(config.with_algo(tiny, "hgg")) == "sparse"


def test_hgg_cost_matrix_matches_a_hand_computed_case():
    # gamma 0.5: 1/(1-gamma) = 2; D (1-gamma) / L = 4 * 0.5 / 2 = 1; c = 3.
    targets = jnp.array([[0.0, 0.0], [3.0, 4.0]])
    traj = jnp.array([[[0.0, 0.0], [3.0, 0.0]], [[1.0, 0.0], [3.0, 4.0]]])
    values = jnp.array([[2.0, 0.0], [1.0, 3.0]])  # HGG scale: [[0, -2], [-1, 0]] (clipped)
    cost, cands = hgg.cost_matrix(
        targets, jnp.zeros(2), traj, traj[:, 0], values,
        diameter=4.0, gamma=0.5, init_distance_weight=3.0, lipschitz=2.0,
    )  # fmt: skip
    # Edge (j, k) = min_t(||g_kt - g_j|| - V_hgg) + 3 ||g_k0 - s0||:
    # (0,0): min(0-0, 3+2) + 0 = 0;          (0,1): min(1+1, 5-0) + 3 = 5;
    # (1,0): min(5-0, 4+2) + 0 = 5;          (1,1): min(sqrt(20)+1, 0-0) + 3 = 3.
    np.testing.assert_allclose(cost, [[0.0, 5.0], [5.0, 3.0]], atol=1e-6)
    np.testing.assert_allclose(cands, [[[0, 0], [1, 0]], [[0, 0], [3, 4]]], atol=1e-6)


def test_hgg_proposes_the_optimal_matching(maze):
    """HGG's goals are the argmin states of scipy's optimal assignment on its costs."""
    cfg = config.with_algo(config.preset("medium_maze", "tiny"), "hgg")
    cfg = dataclasses.replace(cfg, curriculum=dataclasses.replace(cfg.curriculum, n_slots=6))
    cur = interface.make_curriculum(cfg, maze, None)
    k_pool, k_obs, k_prop = jax.random.split(jax.random.key(3), 3)
    pool_ag = jax.random.uniform(k_pool, (15, 9, 2), minval=-16.0, maxval=16.0)
    pool_obs = jax.random.normal(k_obs, (15, 9, 5))
    value_fn = lambda obs, goals: 40.0 * jnp.tanh(obs[..., 0] + goals[..., 0] / 10.0) + 50.0  # noqa: E731
    start = jnp.asarray(maze.start_goal, jnp.float32)
    inputs = interface.CurriculumInputs(
        pool_ag, pool_obs, jnp.ones(15, bool), start, None, None, value_fn,
        curriculum.hyperparams(cfg.curriculum),
    )  # fmt: skip
    goals, metrics, _ = cur.propose(None, inputs, k_prop)
    # The same targets and costs, solved by scipy.
    targets = curriculum.goal_slots(maze, 6, jax.random.split(k_prop)[0])
    traj = curriculum.subsample(pool_ag, cfg.curriculum.cost_stride)
    values = value_fn(jnp.broadcast_to(pool_obs[:, :1], traj.shape[:2] + (5,)), traj)
    cost, cands = hgg.cost_matrix(
        targets, start, traj, pool_ag[:, 0], values,
        diameter=curriculum.start_to_desired_distance(maze, start), gamma=cfg.sac.gamma,
        init_distance_weight=3.0, lipschitz=5.0,
    )  # fmt: skip
    rows, cols = scipy.optimize.linear_sum_assignment(np.asarray(cost))
    np.testing.assert_allclose(goals, maze.clip_goal(np.asarray(cands)[rows, cols]), atol=1e-5)
    np.testing.assert_allclose(
        metrics["curriculum/matched_cost"], cost[rows, cols].mean(), rtol=1e-5
    )


@pytest.mark.slow  # minutes cold on 2 cores; HGG trains once in the default suite above
def test_hgg_resume_equals_uninterrupted(tmp_path):
    # A matching every iteration, so resumed iterations rematch on a restored pool.
    extra = ("--curriculum.rematch-every", "400", "--total-steps", "800")
    full = strip_time(_train_tiny("medium_maze", "hgg", tmp_path / "full", *extra))
    assert any(r["curriculum/pool_full"] == 1.0 for r in full)
    path = tmp_path / "resumed"
    _train_tiny(
        "medium_maze", "hgg", path, "--curriculum.rematch-every", "400", "--total-steps", "400"
    )
    cfg, _, _ = cli.parse_args(
        ["--env", "medium_maze", "--preset", "tiny", "--algo", "hgg", *extra]
    )
    assert loop.train(cfg, path, resume=True, quiet=True) == 0
    resumed = strip_time(logging_lib.read_metrics(path / "metrics.jsonl"))
    assert resumed == full


# --- the comparison command ---------------------------------------------------------


def test_summary_reads_targets_and_modes_per_seed():
    from benchmarks import compare

    rows = [
        {"env_steps": 10, "eval/success": [0.1, 0.9], "eval/success/0": [0.2, 1.0],
         "eval/success/1": [0.0, 0.8], "curriculum/distance": [5.0, 1.0]},
        {"env_steps": 20, "sac/critic_loss": [1.0, 1.0]},
        {"env_steps": 30, "eval/success": [0.8, 0.5], "eval/success/0": [1.0, 0.5],
         "eval/success/1": [0.6, 0.5], "curriculum/distance": [2.0, 3.0]},
    ]  # fmt: skip
    s = compare.summarize(rows)
    assert s["env_steps"] == 30 and s["to_target"] == [30.0, 10.0]
    np.testing.assert_allclose(s["best"], [0.8, 0.9])
    np.testing.assert_allclose(s["final_per_mode"][1], [0.6, 0.5])
    table = compare.markdown_table({"d2c": s})
    assert "| d2c | 2 | 30 | 0.65 ± 0.15 | 0.85 ± 0.05 |" in table


@pytest.mark.slow  # the training it runs is loop.train's, tested above; this is the command
def test_compare_trains_each_algo_and_writes_table_and_figure(tmp_path):
    from benchmarks import compare

    out = tmp_path / "cmp"
    argv = ["--env", "medium_maze", "--preset", "tiny", "--algos", "her,hgg", "--seeds", "2"]
    assert compare.main([*argv, "--out", str(out)]) == 0
    table = (out / "comparison.md").read_text().splitlines()
    assert [line.split("|")[1].strip() for line in table[2:]] == ["her", "hgg"]
    assert all(line.split("|")[2].strip() == "2" for line in table[2:])
    assert (out / "comparison.png").read_bytes()[:4] == b"\x89PNG"
    # A second call finds both runs finished and only reports them.
    assert compare.main([*argv, "--out", str(out), "--report-only"]) == 0
    assert compare.main([*argv, "--out", str(out), "--algos", "d2c,nope"]) == 2


@pytest.mark.slow  # test_sweep's arm-equals-single-run covers the mechanism
def test_hgg_sweep_arm_equals_its_single_run(tmp_path):
    """--algo under --sweep: each arm's run is the single run with that value and seed."""
    swept = _train_tiny("medium_maze", "hgg", tmp_path / "sweep", "--sweep", "sac.tau=0.005,0.02")
    single = _train_tiny("medium_maze", "hgg", tmp_path / "one", "--sac.tau", "0.02")
    for row_sweep, row_single in zip(strip_time(swept), strip_time(single), strict=True):
        for key, value in row_single.items():
            if isinstance(row_sweep[key], list):
                np.testing.assert_allclose(row_sweep[key][1], value, rtol=1e-5, err_msg=key)


class _EpisodeCounter(interface.HERDesired):
    """A stateful probe curriculum: counts the episodes and successes it has observed."""

    def init(self, key):
        return {"episodes": jnp.zeros((), jnp.int32), "successes": jnp.zeros((), jnp.int32)}

    def observe(self, state, episodes, inputs):
        reached = episodes.success.any(axis=1).sum().astype(jnp.int32)
        return {"episodes": state["episodes"] + episodes.success.shape[0],
                "successes": state["successes"] + reached}, {}  # fmt: skip


def test_a_curriculum_state_observes_every_iteration_and_is_checkpointed(maze, tmp_path):
    from d2c_jax.training import runs

    cfg = config.with_algo(config.preset("medium_maze", "tiny"), "her")
    agent = agent_lib.Agent(cfg, maze)
    agent.curriculum = _EpisodeCounter(cfg, maze, agent.classifier_net)
    step = jax.jit(agent.step)
    ts = agent.init(jax.random.key(0))
    successes = 0
    for _ in range(3):
        ts, metrics = step(ts)
        successes += round(float(metrics["train/success_rate"]) * cfg.num_envs)
    assert int(ts.curriculum_state["episodes"]) == 3 * cfg.num_envs
    assert int(ts.curriculum_state["successes"]) == successes
    ckpt = runs.open_checkpointer(tmp_path)
    runs.save_state(ckpt, 3, ts)  # returns once the checkpoint is on disk
    _, restored = runs.restore_or_fail(ckpt, agent.init(jax.random.key(1)), tmp_path)
    ckpt.close()
    assert int(restored.curriculum_state["episodes"]) == 3 * cfg.num_envs
    assert int(restored.curriculum_state["successes"]) == successes
