"""Sweeps (issue 13): arms x seeds as one program, sharded over devices and processes."""

import dataclasses
import os
import pathlib
import socket
import subprocess
import sys

import numpy as np
import pytest

from d2c_jax import config, config_io
from d2c_jax.training import cli, commands, loop, placement, runs, sweep
from d2c_jax.training import logging as logging_lib

ROOT = pathlib.Path(__file__).resolve().parents[1]
TINY = ["--env", "medium_maze", "--preset", "tiny"]
# Three runs: an odd number, so two devices or two processes need a padding run.
LAMBDA_SWEEP = ["--sweep", "classifier.diversity-weight=0,1,2"]


def train_in_process(path, *args) -> list[dict]:
    cfg, _, _ = cli.parse_args([*TINY, *args])
    assert loop.train(cfg, path, quiet=True) == 0
    return logging_lib.read_metrics(path / "metrics.jsonl")


def run_cli(*args, extra_env=None, timeout=600) -> subprocess.Popen:
    env = {**os.environ, "JAX_PLATFORMS": "cpu", **(extra_env or {})}
    return subprocess.Popen(
        [sys.executable, "train.py", *args],
        cwd=ROOT,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def finish(proc: subprocess.Popen, timeout=600) -> None:
    out, err = proc.communicate(timeout=timeout)
    assert proc.returncode == 0, err[-3000:]


def run_values(row: dict, run: int | None = None) -> dict:
    """A metrics row's values (time/* and counters dropped): run `run`'s of a sweep, or
    all of a single run's."""
    skip = ("time/", "iteration", "env_steps")
    pick = (lambda v: np.asarray(v)) if run is None else (lambda v: np.asarray(v)[run])
    return {k: pick(v) for k, v in row.items() if not k.startswith(skip)}


def assert_rows_close(got: list[dict], want: list[dict]) -> None:
    assert len(got) == len(want)
    for g, w in zip(got, want, strict=True):
        keys = {k for k in w if not k.startswith("time/")}
        assert keys == {k for k in g if not k.startswith("time/")}
        for k in keys:
            np.testing.assert_allclose(
                np.asarray(g[k], float), np.asarray(w[k], float), rtol=1e-4, atol=1e-6, err_msg=k
            )


@pytest.fixture(scope="module")
def unsharded(tmp_path_factory) -> list[dict]:
    """The three-run lambda sweep on one device of one process."""
    return train_in_process(tmp_path_factory.mktemp("sweep") / "run", *LAMBDA_SWEEP)


# --- the run axis -----------------------------------------------------------------------


def test_runs_are_arms_times_seeds_with_the_last_sweep_fastest():
    cfg, _, _ = cli.parse_args(
        [
            *TINY,
            "--seed",
            "5",
            "--seeds",
            "2",
            "--sweep",
            "sac.tau=0.1,0.2",
            "--sweep",
            "reward=intrinsic,sparse",
        ]
    )
    runs = sweep.run_configs(cfg)
    got = [(c.sac.tau, c.reward, c.seed) for c in runs]
    want = [
        (t, r, s) for t in (0.1, 0.2) for r in ("intrinsic", "sparse") for s in (5, 6)
    ]  # fmt: skip
    assert got == want
    assert sweep.n_runs(cfg) == 8 and all(c.sweep == () and c.num_seeds == 1 for c in runs)


def test_layout_pads_each_process_to_whole_device_blocks():
    layout = placement.RunLayout(n_runs=5, n_processes=2, process_index=1, n_local_devices=2)
    assert layout.share == 3 and layout.local_size == 4
    assert list(layout.local_runs(0)) == [0, 1, 2] and list(layout.local_runs()) == [3, 4]
    assert layout.local_run_ids().tolist() == [3, 4, 3, 3]  # padding repeats run 3
    # Rows of the gathered (2 x 4) states: process 0's rows 0-2, process 1's rows 4-5.
    assert layout.gathered_rows().tolist() == [0, 1, 2, 4, 5]
    one = placement.RunLayout(n_runs=1, n_processes=2, process_index=1, n_local_devices=1)
    assert list(one.local_runs()) == [] and one.local_run_ids().tolist() == [0]


# Two fields in the default suite (the switch-like reward and a float); every field under
# `slow` (two traces each).
_DEFAULT_SWEEP_FIELDS = ("reward", "classifier.lr")


@pytest.mark.parametrize(
    "field",
    [f if f in _DEFAULT_SWEEP_FIELDS else pytest.param(f, marks=pytest.mark.slow)
     for f in sweep.SWEEPABLE_FIELDS],
)  # fmt: skip
def test_every_sweepable_field_is_a_traced_input_of_the_step(field, medium_maze):
    """Two configs that differ only in a swept field's own value compile to the same
    program, whose hyperparameters differ: the value is data, not a constant."""
    import jax

    from d2c_jax.training import agent as agent_lib

    base = config.preset("medium_maze", "tiny")
    base = dataclasses.replace(
        base,
        curriculum=dataclasses.replace(base.curriculum, post_success_rule="outpace"),
    )
    values = ("intrinsic", "sparse") if field == "reward" else (0.3, 0.6)
    swept = dataclasses.replace(base, sweep=((field, values),))
    programs, hparams = [], []
    for value in values:
        agent = agent_lib.Agent(config_io.replace_field(swept, field, value), medium_maze)
        ts = jax.eval_shape(agent.init_runs)
        programs.append(agent_lib.jit_step(agent).lower(ts).as_text())
        hparams.append(agent_lib.hyperparams(config_io.replace_field(base, field, value)))
    assert programs[0] == programs[1]
    leaves = [jax.tree.leaves(h) for h in hparams]
    assert any(not np.array_equal(a, b) for a, b in zip(*leaves, strict=True))


# --- a sweep equals its single runs -----------------------------------------------------


def test_a_sweep_arm_with_seed_s_equals_the_single_run(tmp_path):
    """The two switch-like fields (reward variant, value term on/off), seed 1 (not the
    default 0, so the run's seed reaches its arm)."""
    swept = train_in_process(
        tmp_path / "sweep",
        "--seed", "1",
        "--sweep", "reward=intrinsic,sparse",
        "--sweep", "curriculum.goal-value-weight=0,1",
    )  # fmt: skip
    # Arms: (intrinsic, 0), (intrinsic, 1), (sparse, 0), (sparse, 1); run = arm (1 seed).
    # Arm (sparse, 1) holds both switches; each single run is a compile.
    singles = {
        3: train_in_process(
            tmp_path / "a", "--reward", "sparse", "--curriculum.goal-value-weight", "1",
            "--seed", "1",
        ),
    }  # fmt: skip
    for run, rows in singles.items():
        for s_row, row in zip(swept, rows, strict=True):
            want, got = run_values(row), run_values(s_row, run)
            assert set(got) == set(want)
            for k in want:
                np.testing.assert_allclose(got[k], want[k], rtol=1e-4, atol=1e-6, err_msg=k)


# --- devices and processes --------------------------------------------------------------


@pytest.mark.slow  # subprocesses compiling cold on two host devices: minutes on 2 cores
def test_sharded_sweep_and_its_resume_equal_the_unsharded_run(unsharded, tmp_path):
    """Two host devices: three runs padded to four; then a run stopped after one
    iteration and resumed gives the same rows."""
    two_devices = {"XLA_FLAGS": "--xla_force_host_platform_device_count=2"}
    full, part = tmp_path / "full", tmp_path / "part"
    finish(run_cli(*TINY, *LAMBDA_SWEEP, "--out", str(full), extra_env=two_devices))
    assert_rows_close(logging_lib.read_metrics(full / "metrics.jsonl"), unsharded)
    finish(
        run_cli(
            *TINY, *LAMBDA_SWEEP, "--out", str(part), "--total-steps", "400", extra_env=two_devices
        )
    )
    # One device cannot take over the two devices' padded states: refused, not garbled.
    cfg, _, _ = cli.parse_args([*TINY, *LAMBDA_SWEEP])
    with pytest.raises(runs.RunError, match="resume with the processes and devices") as err:
        loop.train(cfg, part, resume=True, quiet=True)
    assert err.value.status == 2
    finish(run_cli(*TINY, *LAMBDA_SWEEP, "--out", str(part), "--resume", extra_env=two_devices))
    assert_rows_close(logging_lib.read_metrics(part / "metrics.jsonl"), unsharded)
    assert_loads_the_real_runs(full, 3)
    # Run 3 is a padding row of the checkpoint, not a run: refused, not drawn.
    assert commands.render_main([str(full), "--seed-index", "3"]) == 2


def assert_loads_the_real_runs(run_dir, n_runs: int) -> None:
    """`load_run` (render, evaluation) gets the real runs in run order, no padding."""
    import jax

    _, _, ts = runs.load_run(run_dir)
    assert ts.iteration.shape == (n_runs,) and np.all(np.asarray(ts.iteration) == 2)
    lambdas = np.asarray(ts.hparams.classifier.diversity_weight)
    np.testing.assert_allclose(lambdas, [0.0, 1.0, 2.0])
    assert jax.tree.leaves(ts.sac)[0].shape[0] == n_runs


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("localhost", 0))
        return s.getsockname()[1]


@pytest.mark.slow  # two processes, each compiling cold: minutes on 2 cores
def test_two_processes_split_a_sweep_and_resume(unsharded, tmp_path):
    """Two processes joined by jax.distributed (gloo on CPU): process 0 runs runs 0-1,
    process 1 run 2 and a padding run; process 0 writes the rows of all three, each
    process checkpoints its own runs, and a resumed job continues them."""
    out = tmp_path / "run"

    def job(*args):
        port = free_port()
        procs = [
            run_cli(
                *TINY,
                *LAMBDA_SWEEP,
                "--out",
                str(out),
                *args,
                "--coordinator",
                f"localhost:{port}",
                "--num-processes",
                "2",
                "--process-id",
                str(i),
            )  # fmt: skip
            for i in range(2)
        ]
        for proc in procs:
            finish(proc)

    job("--total-steps", "400")
    assert sorted(p.name for p in (out / "checkpoints").iterdir()) == [
        "layout.json",
        "process-0-of-2",
        "process-1-of-2",
    ]
    job("--resume")
    assert_rows_close(logging_lib.read_metrics(out / "metrics.jsonl"), unsharded)
    assert_loads_the_real_runs(out, 3)


# --- bad input --------------------------------------------------------------------------


@pytest.mark.parametrize(
    "args, first_line",
    [
        (["--sweep", "sac.nope=1,2"], "error: --sweep sac.nope: unknown field; sweepable: "),
        (["--sweep", "sac.hidden-sizes=32,64"], "error: --sweep sac.hidden-sizes: cannot be swept"),
        (["--sweep", "num-envs=2,4"], "error: --sweep num-envs: cannot be swept"),
        (["--sweep", "sac.tau"], "error: --sweep 'sac.tau' must be FIELD=V1,V2,..."),
        (["--sweep", "sac.tau=0.1,,0.2"], "error: --sweep 'sac.tau=0.1,,0.2': empty value"),
        (["--sweep", "sac.tau=fast"], "error: --sweep sac.tau must be float, got 'fast'"),
        (["--sweep", "reward=dense"], "error: --sweep reward must be one of intrinsic, sparse"),
        (["--sweep", "her.relabel-prob=0,2"], "error: --her.relabel-prob must be in [0, 1], got 2"),
        (["--sweep", "sac.tau=0.1", "--sweep", "sac.tau=0.2"], "error: --sweep sac.tau is given"),
        (["--preset", "quick", "--seeds", "100000"], "error: 100000 runs need about"),
    ],
)  # fmt: skip
def test_bad_sweeps_exit_2_with_one_line(args, first_line, tmp_path, capsys):
    argv = ["--env", "medium_maze", "--preset", "tiny", *args, "--out", str(tmp_path / "r")]
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert err.splitlines()[0].startswith(first_line), err
    assert len(err.splitlines()) == 1
    assert not (tmp_path / "r").exists()  # refused before the run directory is made
