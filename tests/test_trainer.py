"""The trainer end to end with the tiny preset: determinism, resume, seeds, bad input."""

import dataclasses
import json
import os
import pathlib
import subprocess
import sys

import numpy as np
import pytest

from d2c_jax import config, config_io
from d2c_jax.training import agent as agent_lib
from d2c_jax.training import cli, loop, placement, programs, runs
from d2c_jax.training import logging as logging_lib

ROOT = pathlib.Path(__file__).resolve().parents[1]


def run_cli(*args: str, cwd=ROOT, timeout=600) -> subprocess.CompletedProcess:
    env = {**os.environ, "JAX_PLATFORMS": "cpu"}
    return subprocess.run(
        [sys.executable, "train.py", *args],
        capture_output=True,
        text=True,
        cwd=cwd,
        timeout=timeout,
        env=env,
    )


def strip_time(rows: list[dict]) -> list[dict]:
    return [{k: v for k, v in r.items() if not k.startswith("time/")} for r in rows]


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    """Two tiny runs of the same seed (in process), and their metrics."""
    out = []
    for name in ("a", "b"):
        path = tmp_path_factory.mktemp(name) / "run"
        cfg, _, _ = cli.parse_args(["--env", "medium_maze", "--preset", "tiny"])
        assert loop.train(cfg, path) == 0
        out.append(path)
    return out


def test_tiny_preset_runs_two_iterations_and_writes_files(tiny_run):
    path = tiny_run[0]
    rows = logging_lib.read_metrics(path / "metrics.jsonl")
    assert [r["iteration"] for r in rows] == [1, 2]
    assert rows[-1]["env_steps"] == 2 * 4 * 100
    last = rows[-1]
    assert "eval/success" in last and "curriculum/distance" in last
    assert all(f"eval/success/{k}" in last for k in range(4))
    assert 0.0 <= last["eval/success"] <= 1.0
    assert any(k.startswith("sac/") for k in last) and any(k.startswith("time/") for k in last)
    json.loads((path / "config.json").read_text())
    for name in ("success.png", "curriculum.png", "curriculum_distance.png"):
        assert (path / "plots" / name).read_bytes()[:4] == b"\x89PNG"
    assert (path / "checkpoints").is_dir()


def test_same_seed_gives_identical_metrics(tiny_run):
    a, b = (strip_time(logging_lib.read_metrics(p / "metrics.jsonl")) for p in tiny_run)
    assert a == b


def test_resume_equals_uninterrupted(tiny_run, tmp_path):

    path = tmp_path / "run"
    cfg, _, _ = cli.parse_args(["--env", "medium_maze", "--preset", "tiny", "--total-steps", "400"])
    assert loop.train(cfg, path) == 0  # one iteration, then "killed"
    cfg, _, _ = cli.parse_args(["--env", "medium_maze", "--preset", "tiny"])
    assert loop.train(cfg, path, resume=True) == 0
    resumed = strip_time(logging_lib.read_metrics(path / "metrics.jsonl"))
    full = strip_time(logging_lib.read_metrics(tiny_run[0] / "metrics.jsonl"))
    # The one-iteration run ends with a final evaluation row at iteration 1; resume
    # truncates back to the checkpoint (iteration 1) and continues.
    assert [r["iteration"] for r in resumed] == [1, 2]
    assert resumed[-1] == full[-1]


def test_two_seeds_give_per_seed_lists(tmp_path):

    cfg, _, _ = cli.parse_args(["--env", "medium_maze", "--preset", "tiny", "--seeds", "2"])
    assert loop.train(cfg, tmp_path / "run") == 0
    last = logging_lib.read_metrics(tmp_path / "run" / "metrics.jsonl")[-1]
    assert isinstance(last["eval/success"], list) and len(last["eval/success"]) == 2
    assert isinstance(last["sac/critic_loss"], list) and len(last["sac/critic_loss"]) == 2
    assert isinstance(last["iteration"], int)


@pytest.mark.parametrize(
    "args, first_line",
    [
        (["--env", "nope"], "error: unknown env 'nope'; valid ids: complex_maze"),
        (["--env", "medium_maze", "--total-steps", "-5"], "error: --total-steps must be >= 1"),
        (["--env", "medium_maze", "--preset", "huge"], "error: unknown preset 'huge'"),
        (["--env", "medium_maze", "--sac.nope", "1"], "error: unknown option --sac.nope"),
        (["--env", "medium_maze", "--sac.batch-size", "x"], "error: --sac.batch-size must be int"),
    ],
)
def test_bad_input_exits_2_with_message(args, first_line, tmp_path):
    result = run_cli(*args, "--out", str(tmp_path / "r"))
    assert result.returncode == 2, result.stderr
    assert result.stderr.splitlines()[0].startswith(first_line), result.stderr
    assert "Traceback" not in result.stderr


def test_resume_with_nothing_to_resume_exits_2(tmp_path):
    result = run_cli("--env", "medium_maze", "--preset", "tiny", "--out", str(tmp_path), "--resume")
    assert result.returncode == 2
    assert result.stderr.splitlines()[0].startswith("error: nothing to resume")


def test_resume_refuses_a_changed_method_and_accepts_a_changed_stop_or_save(tmp_path):
    """Only `runs.RESUME_MAY_CHANGE` may differ from the saved config.json."""
    cfg = config.preset("medium_maze", "tiny")
    runs.prepare_run_dir(tmp_path, cfg, resume=False)
    later = dataclasses.replace(cfg, total_steps=8000, checkpoint_every=1, checkpoint_minutes=0.5)
    runs.prepare_run_dir(tmp_path, later, resume=True)
    assert json.loads((tmp_path / "config.json").read_text())["checkpoint_minutes"] == 0.5
    other = dataclasses.replace(later, sac=dataclasses.replace(cfg.sac, gamma=0.9))
    with pytest.raises(runs.RunError, match=r"differs from .*config\.json in \['sac'\]") as err:
        runs.prepare_run_dir(tmp_path, other, resume=True)
    assert err.value.status == 2


class _FakeClock:
    def __init__(self):
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def test_checkpoint_timer_is_due_after_its_minutes_and_never_when_off():
    one_process = placement.RunLayout(n_runs=1, n_processes=1, process_index=0, n_local_devices=1)
    clock = _FakeClock()
    timer, off = loop.CheckpointTimer(2.0, clock), loop.CheckpointTimer(0.0, clock)
    clock.now = 119.9
    assert not timer.due(one_process)
    clock.now = 120.0
    assert timer.due(one_process) and timer.due(one_process)  # due until a save resets it
    timer.reset()
    clock.now = 239.0
    assert not timer.due(one_process)
    clock.now = 1e9
    assert not off.due(one_process)


@pytest.mark.parametrize("minutes, kept", [(1e-9, [2, 3, 4]), (0.0, [4])])
def test_timed_checkpoints_save_between_scheduled_ones(minutes, kept, tmp_path):
    """With checkpoint_every past the run's end, a timer that is always due saves at every
    iteration (the newest 3 kept); with the timer off only the end saves. The timed
    checkpoints change no result: the metrics equal those of the same run without them."""
    args = ["--env", "medium_maze", "--preset", "tiny", "--total-steps", "1600"]
    cfg, _, _ = cli.parse_args(
        [*args, "--checkpoint-every", "1000000", "--checkpoint-minutes", str(minutes)]
    )
    assert loop.train(cfg, tmp_path / "run", quiet=True) == 0
    saved = sorted(int(d.name) for d in (tmp_path / "run" / "checkpoints").iterdir()
                   if d.name.isdigit())  # fmt: skip
    assert saved == kept
    if minutes:
        plain, _, _ = cli.parse_args(args)
        assert loop.train(plain, tmp_path / "plain", quiet=True) == 0
        assert strip_time(logging_lib.read_metrics(tmp_path / "run" / "metrics.jsonl")) == (
            strip_time(logging_lib.read_metrics(tmp_path / "plain" / "metrics.jsonl"))
        )


def test_unreadable_checkpoint_exits_2(tiny_run, tmp_path):
    import shutil

    path = tmp_path / "run"
    shutil.copytree(tiny_run[0], path)
    for f in (path / "checkpoints").rglob("*"):
        if f.is_file():
            f.write_bytes(b"garbage")
    result = run_cli("--env", "medium_maze", "--preset", "tiny", "--out", str(path), "--resume")
    assert result.returncode == 2, result.stderr
    assert result.stderr.splitlines()[0].startswith("error: cannot read checkpoint")
    assert "Traceback" not in result.stderr


def test_plots_command_redraws_a_run_and_refuses_a_non_run(tiny_run, tmp_path):
    import shutil

    path = tmp_path / "run"
    shutil.copytree(tiny_run[0], path)
    shutil.rmtree(path / "plots")
    command = [sys.executable, "-m", "d2c_jax.plots"]
    done = subprocess.run([*command, str(path)], capture_output=True, text=True, cwd=ROOT)
    assert done.returncode == 0, done.stderr
    for name in ("success.png", "curriculum.png", "curriculum_distance.png"):
        assert (path / "plots" / name).read_bytes()[:4] == b"\x89PNG"
    bad = subprocess.run([*command, str(tmp_path)], capture_output=True, text=True, cwd=ROOT)
    assert bad.returncode == 2
    assert bad.stderr.splitlines()[0] == f"error: {tmp_path} is not a run directory: no config.json"


def test_a_checkpoint_of_another_state_layout_is_refused_with_its_reason(tmp_path):
    """A state written by another version (other TrainState fields) is not restored into
    today's: RunError(2) saying so, not orbax's tree diff."""
    import jax.numpy as jnp
    from flax import struct

    from d2c_jax.training import checkpoint

    @struct.dataclass
    class State:
        a: jnp.ndarray
        hparams: jnp.ndarray

    ckpt = runs.open_checkpointer(tmp_path)
    ckpt.save(1, {"a": jnp.zeros(3), "n_episodes": jnp.zeros((), jnp.int32)})
    ckpt.close()
    ckpt = runs.open_checkpointer(tmp_path)
    with pytest.raises(runs.RunError) as err:
        runs.restore_or_fail(ckpt, State(a=jnp.zeros(3), hparams=jnp.zeros(())), tmp_path)
    ckpt.close()
    assert err.value.status == 2
    assert "another layout" in str(err.value).splitlines()[0]
    assert isinstance(err.value.__context__, checkpoint.CheckpointError)


def test_overrides_reach_the_config():
    cfg, out, resume = cli.parse_args(
        [
            "--env",
            "sawyer_push",
            "--preset",
            "quick",
            "--sac.batch-size",
            "128",
            "--sac.hidden-sizes",
            "64,64",
            "--curriculum.variant",
            "none",
            "--seed",
            "3",
        ]
    )
    assert cfg.sac.batch_size == 128 and cfg.sac.hidden_sizes == (64, 64)
    assert cfg.curriculum.variant == "none" and cfg.seed == 3
    assert str(out) == "runs/sawyer_push-quick-3" and not resume
    assert cfg.classifier.eps == 0.025 and cfg.classifier.update_every == 3000  # Table 3


def test_nan_stops_with_status_3_and_keeps_checkpoint(tmp_path):

    # An absurd learning rate makes the critic overflow within the tiny run.
    cfg, _, _ = cli.parse_args(
        [
            "--env",
            "medium_maze",
            "--preset",
            "tiny",
            "--sac.critic-lr",
            "1e30",
            "--total-steps",
            "4000",
        ]
    )
    path = tmp_path / "run"
    with pytest.raises(runs.RunError) as err:
        loop.train(cfg, path)
    assert err.value.status == 3
    assert "non-finite" in str(err.value) and "iteration" in str(err.value)
    rows = logging_lib.read_metrics(path / "metrics.jsonl")
    assert all(np.isfinite(r.get("sac/critic_loss", 0.0)) for r in rows)


def test_schedule_matches_spec_hand_computed_counts():
    from d2c_jax import config

    # config.preset needs no env module, so this holds before envs/ant.py exists.
    # Ant's paper preset: one episode per iteration, 20 slots matched every 20 episodes.
    ant = agent_lib.make_schedule(config.preset("ant", "paper"), horizon=300)
    assert ant == agent_lib.Schedule(
        env_steps=300,
        sac_updates=300,
        classifier_updates=1,  # round(16 * 300 / 4500) = round(1.07)
        warmup_iterations=14,  # ceil(4000 / 300)
        eval_every=34,  # ceil(10,000 / 300)
        total_iterations=10_000,
        rematch_every=20,  # 6000 / 300
        checkpoint_every=500,  # 150,000 env steps, as with 20 envs (25 iterations)
    )
    ant20 = dataclasses.replace(config.preset("ant", "quick"), utd=1.0)
    assert agent_lib.make_schedule(ant20, horizon=300)[:4] == (6000, 6000, 21, 1)
    maze = agent_lib.make_schedule(config.preset("medium_maze", "paper"), horizon=100)
    assert (maze.env_steps, maze.sac_updates, maze.classifier_updates) == (2000, 2000, 16)
    assert (maze.warmup_iterations, maze.eval_every, maze.total_iterations) == (1, 5, 500)
    assert maze.rematch_every == 1
    four_envs = dataclasses.replace(config.preset("medium_maze", "paper"), num_envs=4)
    assert agent_lib.make_schedule(four_envs, horizon=100).rematch_every == 5  # 2000 / 400


@pytest.mark.parametrize("num_envs", [4, 1])  # 1: Ant's paper preset
def test_held_goals_between_matchings_are_used_in_turn(medium_maze, num_envs):
    """rematch_every = 2 iterations: the second iteration keeps the matched goals (and their
    metrics) and its envs take the next slots, K = 2 x num_envs goals over 2 iterations."""
    import jax

    cfg = config.preset("medium_maze", "tiny")
    k = 2 * num_envs
    cfg = dataclasses.replace(
        cfg,
        num_envs=num_envs,
        curriculum=dataclasses.replace(
            cfg.curriculum, n_slots=k, pool_size=k, rematch_every=2 * num_envs * 100
        ),
    )
    agent = agent_lib.Agent(cfg, medium_maze)
    assert agent.schedule.rematch_every == 2
    ts = agent.init_seeds()
    step = programs.jit_step(agent)
    ts1, m1 = step(ts)
    ts2, m2 = step(jax.tree.map(jax.numpy.copy, ts1))
    np.testing.assert_array_equal(ts1.curriculum_goals, ts2.curriculum_goals)
    for key in ("curriculum/distance", "curriculum/pool_full"):
        np.testing.assert_array_equal(m1[key], m2[key])
    goals = np.asarray(ts2.curriculum_goals[0])
    first_goal = np.asarray(ts2.replay.goal[0, :k, 0])  # the first step of each episode
    n = num_envs
    np.testing.assert_array_equal(first_goal[:n], goals[:n])  # iteration 1: slots 0..n-1
    np.testing.assert_array_equal(first_goal[n:], goals[n:])  # iteration 2: the next n
    ts3, _ = step(jax.tree.map(jax.numpy.copy, ts2))
    assert not np.array_equal(ts3.curriculum_goals, ts2.curriculum_goals)  # matched again


def test_the_step_reads_its_hyperparameters_from_the_state(medium_maze):
    """TrainState.hparams are traced inputs of the compiled step (what a sweep vmaps):
    zero learning rates and tau, set in the state after init, freeze every network."""
    import jax

    cfg = config.preset("medium_maze", "tiny")
    agent = agent_lib.Agent(cfg, medium_maze)
    ts = agent.init_seeds()

    def zero():  # a buffer of its own per leaf: the step donates its state
        return jax.numpy.zeros_like(ts.hparams.sac.actor_lr)

    frozen = ts.hparams.replace(
        sac=ts.hparams.sac.replace(actor_lr=zero(), critic_lr=zero(), alpha_lr=zero(), tau=zero()),
        classifier=ts.hparams.classifier.replace(lr=zero()),
    )
    step = programs.jit_step(agent)
    before = jax.tree.map(np.asarray, (ts.sac, ts.classifier.params))
    after, metrics = step(ts.replace(hparams=frozen))
    nets = lambda s: (s.actor_params, s.critic_params, s.target_critic_params, s.log_alpha)  # noqa: E731
    for a, b in zip(
        jax.tree.leaves(nets(before[0])), jax.tree.leaves(nets(after.sac)), strict=True
    ):
        np.testing.assert_array_equal(a, b)
    for a, b in zip(
        jax.tree.leaves(before[1]), jax.tree.leaves(after.classifier.params), strict=True
    ):
        np.testing.assert_array_equal(a, b)
    assert float(metrics["sac/critic_loss"][0]) > 0  # the updates ran, with step size 0


def _maze_agent_with_episodes(cfg, env, achieved_goal, walk_start):
    """One seed's TrainState of `cfg` on `env` with n stored episodes whose achieved goals
    (n, H + 1, 2) and walk starts (n,) are given (everything else zero): (agent, ts)."""
    import jax

    from d2c_jax.core import replay
    from d2c_jax.core.rollout import Episodes

    n, horizon = achieved_goal.shape[0], env.horizon
    episodes = Episodes(
        obs=np.zeros((n, horizon + 1, env.obs_dim), np.float32),
        achieved_goal=achieved_goal,
        action=np.zeros((n, horizon, 2), np.float32),
        goal=np.zeros((n, horizon, 2), np.float32),
        success=np.zeros((n, horizon), bool),
        walk_start=np.asarray(walk_start, np.int32),
    )
    agent = agent_lib.Agent(cfg, env)
    ts = jax.tree.map(lambda x: x[0], agent.init_seeds())
    return agent, ts.replace(replay=replay.insert_episodes(ts.replay, episodes))


def test_archive_rarity_draws_the_episode_that_ended_where_nobody_goes(medium_maze):
    """Nine episodes end at the start, one at a far corner: with archive_rarity the archive
    of one episode is that one for (almost) every key; without it, about one key in ten."""
    import jax

    cfg = config.preset("medium_maze", "tiny")
    horizon, n = medium_maze.horizon, 10
    ag = np.zeros((n, horizon + 1, 2), np.float32)
    ag[-1, -1] = [10.0, 10.0]  # the last state of the last episode
    picked = {}
    for rarity in (0.0, 2.0):
        cur = dataclasses.replace(
            cfg.curriculum, pool_size=4, archive_size=1, archive_rarity=rarity
        )
        agent, ts = _maze_agent_with_episodes(
            dataclasses.replace(cfg, curriculum=cur), medium_maze, ag, np.full(n, horizon)
        )
        pool = jax.jit(jax.vmap(agent._matching_pool, in_axes=(None, 0)))
        slots, _ = pool(ts, jax.random.split(jax.random.key(0), 200))
        picked[rarity] = np.mean(np.asarray(slots)[:, -1] == n - 1)  # the archived row
    assert picked[2.0] > 0.95
    assert 0.03 < picked[0.0] < 0.2


def test_pool_phase_keeps_only_the_states_reached_pursuing_the_curriculum_goal(medium_maze):
    """One episode reaches its goal at step 4 (walk_start 5), walks on along x for four
    steps and then goes to a far corner: with pool_phase="curriculum_phase" the matching
    pool holds s_0..s_5 and then s_5 again; with 3 walk steps kept, s_0..s_8 and then s_8;
    with "all" it holds the corner."""
    cfg = config.preset("medium_maze", "tiny")
    horizon, n = medium_maze.horizon, cfg.curriculum.pool_size
    ag = np.zeros((n, horizon + 1, 2), np.float32)
    ag[-1, :, 0] = np.arange(horizon + 1)  # the newest episode walks along x
    ag[-1, 10:] = [15.0, 15.0]  # from s_10, the walk's corner
    walk_start = np.where(np.arange(n) == n - 1, 5, horizon)
    pools = {}
    for phase, walk_steps in (("all", 0), ("curriculum_phase", 0), ("curriculum_phase", 3)):
        cur = dataclasses.replace(cfg.curriculum, pool_phase=phase, pool_walk_steps=walk_steps)
        agent, ts = _maze_agent_with_episodes(
            dataclasses.replace(cfg, curriculum=cur), medium_maze, ag, walk_start
        )
        pools[phase, walk_steps] = np.asarray(agent.curriculum_inputs(ts).pool_ag[0])
    np.testing.assert_array_equal(pools["all", 0], ag[-1])
    for last_kept in (5, 8):  # walk_start + walk steps kept
        held = pools["curriculum_phase", last_kept - 5]
        np.testing.assert_array_equal(held[: last_kept + 1], ag[-1, : last_kept + 1])
        np.testing.assert_array_equal(
            held[last_kept + 1 :], np.broadcast_to([last_kept, 0.0], (horizon - last_kept, 2))
        )


def test_sigterm_checkpoints_and_resume_continues(tmp_path):
    import signal
    import time

    path = tmp_path / "run"
    args = [
        sys.executable,
        "train.py",
        "--env",
        "medium_maze",
        "--preset",
        "tiny",
        "--total-steps",
        "40000",
        "--out",
        str(path),
    ]
    proc = subprocess.Popen(
        args,
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        env={**os.environ, "JAX_PLATFORMS": "cpu"},
    )
    deadline = time.time() + 300
    while time.time() < deadline and len(logging_lib.read_metrics(path / "metrics.jsonl")) < 2:
        time.sleep(0.5)
    proc.send_signal(signal.SIGTERM)
    assert proc.wait(timeout=120) == 128 + signal.SIGTERM
    rows = logging_lib.read_metrics(path / "metrics.jsonl")
    stopped_at = rows[-1]["iteration"]
    assert "eval/success" in rows[-1]  # the last row is an evaluation row
    assert stopped_at < 100
    steps = sorted(int(p.name) for p in (path / "checkpoints").iterdir() if p.name.isdigit())
    assert steps[-1] == stopped_at and len(steps) <= 3  # saved on the signal, last 3 kept
    result = run_cli(
        "--env",
        "medium_maze",
        "--preset",
        "tiny",
        "--total-steps",
        str((stopped_at + 1) * 400),
        "--out",
        str(path),
        "--resume",
    )
    assert result.returncode == 0, result.stderr
    assert [r["iteration"] for r in logging_lib.read_metrics(path / "metrics.jsonl")] == list(
        range(1, stopped_at + 2)
    )


@pytest.mark.parametrize(
    "override",
    [
        ["--curriculum.variant", "value"],
        pytest.param(["--curriculum.variant", "none"], marks=pytest.mark.slow),
        pytest.param(["--reward", "sparse"], marks=pytest.mark.slow),
        pytest.param(
            ["--curriculum.archive-size", "8", "--curriculum.archive-rarity", "1"],
            marks=pytest.mark.slow,
        ),
        pytest.param(
            [
                "--classifier.goal-candidates",
                "buffer_and_desired",
                "--classifier.n-heads",
                "4",
                "--classifier.diversity-weight",
                "0",
            ],
            marks=pytest.mark.slow,
        ),
    ],
)
def test_ablations_run_one_iteration(override):
    import envs

    cfg, _, _ = cli.parse_args(["--env", "medium_maze", "--preset", "tiny", *override])
    env = envs.make(cfg.env)
    step = agent_lib.make_train_step(cfg, env)  # the contract path
    ts = agent_lib.Agent(cfg, env).init_seeds()
    for _ in range(2):  # a warm-up iteration, then a trained one
        ts, metrics = step(ts)
    assert bool(metrics["health/params_finite"][0])
    assert np.isfinite(float(metrics["sac/critic_loss"][0]))
    if override[1] == "none":  # goals are the desired examples themselves
        assert float(metrics["curriculum/distance"][0]) == 0.0


def test_config_round_trips_through_config_json():
    cfg = config.preset("ant", "tiny")
    assert config_io.from_dict(config.TrainConfig, json.loads(runs.config_to_json(cfg))) == cfg


def test_over_runs_equals_vmap_with_and_without_a_size_one_axis():
    import jax
    import jax.numpy as jnp

    def fn(tree, scale):
        return {"y": tree["a"] @ tree["b"] * scale, "n": tree["a"].sum()}

    rng = np.random.default_rng(0)
    for n in (1, 3):
        tree = {
            "a": jnp.asarray(rng.normal(size=(n, 4, 5))),
            "b": jnp.asarray(rng.normal(size=(n, 5))),
        }
        want = jax.vmap(fn, in_axes=(0, None))(tree, 2.0)
        got = programs.over_runs(fn, n, in_axes=(0, None))(tree, 2.0)
        assert jax.tree.map(jnp.shape, got) == jax.tree.map(jnp.shape, want)
        jax.tree.map(lambda g, w: np.testing.assert_allclose(g, w, rtol=1e-6), got, want)


@pytest.mark.parametrize("cadence, min_future_radii", [(2, 0.0), (1, 0.0), (2, 4.0)])
def test_sac_blocks_drawn_ahead_equal_a_block_by_block_loop(
    medium_maze, monkeypatch, cadence, min_future_radii
):
    """`Agent.sac_blocks` draws HER transitions a chunk at a time (here 3 blocks, so 7
    blocks are 2 chunks and a remainder of 1): the SAC state equals that of a loop that
    draws each block's batches (`her.relabel`, D2C's intrinsic reward) from the i-th key,
    then updates. With the actor and target at every update (`cadence` 1: one-update
    blocks) the loop is unrolled to two blocks per iteration, 3 = one pair and one more.
    `her.min_future_radii` reaches the draws as that many success radii."""
    import jax

    from d2c_jax.core import her, sac
    from d2c_jax.training import sac_loop

    monkeypatch.setattr(sac_loop, "SAMPLE_CHUNK", 3)
    cfg = config.preset("medium_maze", "tiny")
    sac_cfg = dataclasses.replace(cfg.sac, actor_update_every=cadence, target_update_every=cadence)
    her_cfg = dataclasses.replace(cfg.her, min_future_radii=min_future_radii)
    cfg = dataclasses.replace(cfg, sac=sac_cfg, her=her_cfg)
    assert sac.block_size(cfg.sac) == cadence
    agent = agent_lib.Agent(cfg, medium_maze)
    ts, _ = jax.jit(agent.step)(agent.init(jax.random.key(0)))  # a buffer of random episodes
    n, key = 7, jax.random.key(1)

    def block_by_block(ts, min_distance=min_future_radii * medium_maze.success_radius):
        reward_fn = agent.reward_fn(ts)
        hp, block = ts.hparams, sac.block_size(cfg.sac)

        def one(sac_state, k):
            k_draw, k_update = jax.random.split(k)
            batches = jax.vmap(
                lambda kb: her.relabel(
                    hp.relabel_prob,
                    ts.replay,
                    cfg.sac.batch_size,
                    reward_fn,
                    kb,
                    min_distance=min_distance,
                )
            )(jax.random.split(k_draw, block))
            return sac.update_sac_block(
                cfg.sac, agent.sac_nets, agent.sac_optimizers, hp.sac, sac_state, batches,
                agent.env, k_update,
            )  # fmt: skip

        return jax.lax.scan(one, ts.sac, jax.random.split(key, n))[0]

    drawn_ahead = jax.jit(lambda ts: agent.sac_blocks(ts, n, key)[0].sac)(ts)
    reference = jax.jit(block_by_block)(ts)
    assert int(drawn_ahead.step - ts.sac.step) == n * sac.block_size(cfg.sac)
    moved = jax.tree.leaves(ts.sac.critic_params)[0] - jax.tree.leaves(reference.critic_params)[0]
    assert float(abs(moved).max()) > 1e-4  # the updates changed the critic
    for a, b in zip(jax.tree.leaves(drawn_ahead), jax.tree.leaves(reference), strict=True):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=0, atol=1e-6)
    if min_future_radii > 0:  # the filter acted: every future goal used gives other updates
        every_future = jax.jit(lambda ts: block_by_block(ts, 0.0))(ts)
        leaf = lambda s: np.asarray(jax.tree.leaves(s.critic_params)[0])  # noqa: E731
        assert np.abs(leaf(every_future) - leaf(drawn_ahead)).max() > 1e-4


def test_a_signal_while_an_iteration_computes_stops_at_its_end(tmp_path, monkeypatch):
    """The step is dispatched asynchronously, so the host waits for an iteration's
    result in the metrics gather; a SIGTERM that arrives there (simulated by sending it
    from inside that wait, in iteration 1) must stop the run at the end of iteration 1,
    checkpointed and evaluated, not one iteration later."""
    import signal

    calls = []
    gather = loop.placement.gather_runs

    def gather_and_signal(tree, layout):
        if not calls and "eval" not in tree:  # the first iteration's train metrics
            os.kill(os.getpid(), signal.SIGTERM)
        calls.append(1)
        return gather(tree, layout)

    monkeypatch.setattr(loop.placement, "gather_runs", gather_and_signal)
    cfg, _, _ = cli.parse_args(["--env", "medium_maze", "--preset", "tiny"])
    out = tmp_path / "run"
    assert loop.train(cfg, out, quiet=True) == 128 + signal.SIGTERM
    rows = logging_lib.read_metrics(out / "metrics.jsonl")
    assert [r["iteration"] for r in rows] == [1]
    assert "eval/success" in rows[0]
    steps = sorted(int(p.name) for p in (out / "checkpoints").iterdir() if p.name.isdigit())
    assert steps == [1]


def test_many_runs_collect_in_capped_batches_on_cpu_with_the_same_episodes(medium_maze):
    """With 2 runs of 150 envs on CPU each run collects, and evaluates, at most 100
    episodes per call (`rollout.MAX_CPU_ENV_BATCH` shared by the runs: jaxlib's batched
    Cholesky deadlocks above it), and the episodes and scores are those of one call."""
    import jax

    from d2c_jax.core import rollout

    cfg = dataclasses.replace(
        config.preset("medium_maze", "tiny"), num_envs=150, num_seeds=2, eval_episodes=30
    )  # 4 modes x 30 = 120 evaluation episodes
    agent = agent_lib.Agent(cfg, medium_maze)
    assert jax.default_backend() == "cpu"
    assert agent.episode_batch == rollout.MAX_CPU_ENV_BATCH // 2 < cfg.num_envs
    ts = agent.init(jax.random.key(0))
    goals = agent.env_goals(ts, ts.curriculum_goals)
    collect = lambda ts, key: agent.collect_episodes(ts, goals, jax.numpy.asarray(True), key)  # noqa: E731
    capped = jax.jit(collect)(ts, jax.random.key(1))
    capped_eval = jax.jit(agent.evaluate)(ts, jax.random.key(2))
    agent.episode_batch = None
    whole = jax.jit(collect)(ts, jax.random.key(1))
    whole_eval = jax.jit(agent.evaluate)(ts, jax.random.key(2))
    assert capped.obs.shape[0] == cfg.num_envs
    for a, b in zip(jax.tree.leaves(capped), jax.tree.leaves(whole), strict=True):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=0, atol=1e-5)
    assert capped_eval.keys() == whole_eval.keys()
    for name in whole_eval:
        np.testing.assert_array_equal(capped_eval[name], whole_eval[name])
