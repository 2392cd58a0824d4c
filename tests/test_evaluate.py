"""`python -m d2c_jax.evaluate RUN_DIR`: the run's own evaluation numbers again.

A tiny run succeeds nowhere, so equal zeros would prove nothing. The module's run is
trained once with a probe in place of the episodes of `rollout.evaluate`: per-mode values
that change with the key (seed, iteration), the policy's parameters and the episode
count. Everything around it is the real code path (Agent.evaluate, jit_evaluate, the
keys, the checkpoints); evaluating with the same probe must reproduce the metrics rows
exactly, so the same state, key and episode count were used. The real episodes run once,
unpatched.
"""

import contextlib
import fcntl
import json
import os
import pathlib
import shutil
import subprocess
import sys

import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from d2c_jax.core import rollout
from d2c_jax.training import cli, evaluation, loop, runs
from d2c_jax.training import logging as logging_lib

SEEDS = 2


def probe_evaluate(env, policy, episodes_per_mode, key, max_batch=None):
    """Stands in for `rollout.evaluate`: (n_modes,) values in [0, 1] that depend on the
    key, on the deterministic policy's parameters and on the episode count (it plays no
    episodes, so `max_batch` does not matter)."""
    obs = jnp.zeros(env.obs_dim)
    goals = jnp.asarray(env.goal_points, jnp.float32)
    actions = jax.vmap(lambda g: policy(obs, g, key))(goals)  # (n_modes, action_dim)
    draw = jax.random.uniform(key, (env.n_modes,))
    return jnp.abs(jnp.sin(1e3 * actions.sum(-1) + episodes_per_mode * draw))


@pytest.fixture
def probe(monkeypatch):
    monkeypatch.setattr(rollout, "evaluate", probe_evaluate)


@contextlib.contextmanager
def exclusive(lock_path: pathlib.Path):
    """Holds an exclusive lock on `lock_path` (POSIX flock) while the block runs."""
    with open(lock_path, "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)


@pytest.fixture(scope="module")
def probe_run(tmp_path_factory):
    """A tiny two-seed run (2 iterations, evaluated and checkpointed at both) trained with
    the probe; its directory and its metrics rows by iteration.

    Trained once per session: under xdist the workers share it (the first trains it
    under a lock; the others wait and read it), since `-n 2` may send this module's
    tests to both workers and a module fixture would then train twice.
    """
    root = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        root = root.parent  # this session's folder, above each worker's own
    path = root / "evaluate-probe-run"
    with exclusive(root / "evaluate-probe-run.lock"):
        if not (path / "trained").is_file():
            shutil.rmtree(path, ignore_errors=True)  # a run whose training failed
            argv = ["--env", "medium_maze", "--preset", "tiny", "--seeds", str(SEEDS)]
            cfg, _, _ = cli.parse_args(argv)
            with pytest.MonkeyPatch.context() as patch:
                patch.setattr(rollout, "evaluate", probe_evaluate)
                assert loop.train(cfg, path, quiet=True) == 0
            (path / "trained").touch()
    rows = {r["iteration"]: r for r in logging_lib.read_metrics(path / "metrics.jsonl")}
    assert all("eval/success" in rows[i] for i in (1, 2))
    return path, rows


def eval_values(record: dict) -> dict:
    return {k: v for k, v in record.items() if k.startswith("eval/")}


def test_default_reproduces_the_newest_evaluation_row(probe_run, probe, capsys):
    path, rows = probe_run
    assert evaluation.main([str(path)]) == 0
    record = json.loads((path / "evaluation-2.json").read_text())
    assert record["iteration"] == 2 and record["episodes_per_mode"] == 2
    assert record["seeds"] == [0, 1] and record["run_dir"] == str(path)
    want = eval_values(rows[2])
    assert len(want) == 1 + 4  # overall and the medium maze's four modes
    assert eval_values(record) == want  # exactly: lists of one float per seed
    assert want["eval/success/0"][0] != want["eval/success/0"][1]  # not a constant
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith("medium_maze: iteration 2 (")
    assert out[1].startswith("  seed 0: success ") and out[2].startswith("  seed 1: success ")
    assert out[-1] == f"wrote {path / 'evaluation-2.json'}"


def test_checkpoint_and_episodes_pick_the_state_and_the_count(probe_run, probe):
    """--checkpoint 1 reproduces iteration 1's row; another episode count changes the
    numbers and goes to a file of its own."""
    path, rows = probe_run
    older = evaluation.evaluate_run(path, checkpoint=1)
    assert older["iteration"] == 1 and eval_values(older) == eval_values(rows[1])
    assert eval_values(rows[1]) != eval_values(rows[2])
    assert evaluation.main([str(path), "--checkpoint", "1", "--episodes", "3"]) == 0
    record = json.loads((path / "evaluation-1-3-episodes.json").read_text())
    assert record["episodes_per_mode"] == 3
    assert eval_values(record).keys() == eval_values(rows[1]).keys()
    assert eval_values(record) != eval_values(rows[1])


@pytest.mark.parametrize(
    "args, message",
    [
        (["missing"], "is not a run directory: no config.json"),
        (["empty"], "is not a run directory: no config.json"),
        (["run", "--checkpoint", "7"], "no checkpoint of iteration 7; it has iterations 1, 2"),
        (["run", "--episodes", "0"], "--episodes must be at least 1, got 0"),
        (["run", "--episodes", "-3"], "--episodes must be at least 1, got -3"),
        (["run", "--episodes", "many"], "argument --episodes: invalid int value: 'many'"),
    ],
)
def test_bad_input_exits_2_with_one_line(probe_run, tmp_path, capsys, args, message):
    (tmp_path / "empty").mkdir()
    places = {"missing": tmp_path / "missing", "empty": tmp_path / "empty", "run": probe_run[0]}
    assert evaluation.main([str(places[args[0]]), *args[1:]]) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    (line,) = captured.err.splitlines()
    assert line.startswith("error: ") and message in line


def test_real_episodes_give_per_seed_success_per_mode(probe_run):
    """Unpatched: one episode per mode either reaches its goal or not."""
    path, _ = probe_run
    record = evaluation.evaluate_run(path, episodes=1)
    per_mode = np.array([record[f"eval/success/{k}"] for k in range(4)])  # (modes, seeds)
    assert per_mode.shape == (4, SEEDS)
    assert set(per_mode.ravel()) <= {0.0, 1.0}
    np.testing.assert_allclose(record["eval/success"], per_mode.mean(axis=0), rtol=1e-6)


def test_command_refuses_a_missing_checkpoint_in_one_line(probe_run):
    """The module entry point: exit 2, one line on stderr (no traceback), nothing on stdout."""
    path, _ = probe_run
    out = subprocess.run(
        [sys.executable, "-m", "d2c_jax.evaluate", str(path), "--checkpoint", "3"],
        capture_output=True,
        text=True,
        env={**os.environ, "JAX_PLATFORMS": "cpu"},
        timeout=300,
    )
    assert out.returncode == 2 and out.stdout == ""
    assert out.stderr.splitlines() == [
        f"error: {path} has no checkpoint of iteration 3; it has iterations 1, 2"
    ]


def test_one_run_of_a_directory_and_the_critic_probe_on_it(probe_run, capsys):
    """`runs.load_one_run` is run `seed_index` of `load_run` without the run axis, and
    refuses an index outside the runs; the critic and reward probes read a run through it."""
    from benchmarks import critic_probe, reward_probe

    path, _ = probe_run
    _, _, both = runs.load_run(path)
    _, _, second = runs.load_one_run(path, 1)
    chex.assert_trees_all_equal(second, jax.tree.map(lambda x: x[1], both))
    with pytest.raises(runs.RunError, match=r"--seed-index must be in \[0, 2\) for .*, got 2"):
        runs.load_one_run(path, 2)
    assert critic_probe.main([str(path), "--seed-index", "1", "--episodes", "4"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0] == f"{path}: {int(both.env_steps[1]):,} env steps"
    assert sum(line.startswith("V(s_0, mode ") for line in out) == 4  # medium_maze's modes
    for probe_main in (critic_probe.main, reward_probe.main):  # jax would clamp index 2
        assert probe_main([str(path), "--seed-index", "2"]) == 2
        (line,) = capsys.readouterr().err.splitlines()
        assert line == f"error: --seed-index must be in [0, 2) for {path}, got 2"
