"""Evaluating a trained run again, without writing code:

    python -m d2c_jax.evaluate RUN_DIR [--episodes N] [--checkpoint ITERATION]

The numbers are the training loop's own: the jitted `Agent.evaluate` over the run axis
(`agent.jit_evaluate`, SPEC §7), the key of each run and iteration (`loop.eval_keys`),
the config's episodes per mode (`eval_episodes`), on the state restored from the
checkpoint of that iteration. So for the checkpoint of an evaluation iteration they equal
that iteration's `eval/*` values in metrics.jsonl (on the same kind of device; a run
trained with its runs split over several devices is evaluated here on one, which may
change float rounding). Results are printed and written to
RUN_DIR/evaluation-<iteration>.json (`-<N>-episodes` added for another episode count).
"""

from __future__ import annotations

import dataclasses
import json
import pathlib
import sys

import numpy as np

import envs
from d2c_jax.training import agent as agent_lib
from d2c_jax.training import cli, loop, placement, programs, runs, sweep
from d2c_jax.training import logging as logging_lib
from d2c_jax.viewing import plots


def evaluate_run(run_dir, episodes: int | None = None, checkpoint: int | None = None) -> dict:
    """Evaluates the runs of a run directory as the training loop does.

    Args:
      run_dir: a directory written by train.py.
      episodes: episodes per goal mode (default: the config's `eval_episodes`, which
        reproduces the run's own evaluation).
      checkpoint: the iteration whose checkpoint to evaluate (default: the newest).
    Returns:
      A JSON-ready record: `iteration`, `env_steps`, `episodes_per_mode`, `seeds` (one
      per run) and the metrics row's `eval/success` and `eval/success/<k>`: numbers for
      one run, lists with one entry per run (arms x seeds, run order) for several.
    Raises:
      RunError(2): episodes < 1, not a run directory, no checkpoint (at `checkpoint`:
        the message lists those there are), or an unreadable one.
    """
    if episodes is not None and episodes < 1:
        raise runs.RunError(f"--episodes must be at least 1, got {episodes}", 2)
    cfg = runs.read_config(run_dir)
    if episodes is not None:
        cfg = dataclasses.replace(cfg, eval_episodes=episodes)
    agent = agent_lib.Agent(cfg, envs.make(cfg.env))
    iteration, ts = runs.restore_runs(agent, run_dir, checkpoint)
    # Every run on one device, as load_run gathered them: keys in run order.
    everything_here = placement.RunLayout(agent.num_runs, 1, 0, 1)
    keys = loop.eval_keys(agent, everything_here, None, iteration)
    metrics = loop.host_metrics(programs.jit_evaluate(agent)(ts, keys), agent.num_runs)
    return {
        "iteration": iteration,
        "env_steps": iteration * agent.schedule.env_steps,
        "episodes_per_mode": cfg.eval_episodes,
        "seeds": sweep.run_seeds(cfg),
        **{k: logging_lib.to_jsonable(v) for k, v in metrics.items()},
    }


def record_path(run_dir, record: dict, default_episodes: int) -> pathlib.Path:
    """RUN_DIR/evaluation-<iteration>.json, with `-<N>-episodes` before the suffix when
    the episodes per mode differ from the run's own (so the run's numbers are kept)."""
    name = f"evaluation-{record['iteration']}"
    if record["episodes_per_mode"] != default_episodes:
        name += f"-{record['episodes_per_mode']}-episodes"
    return pathlib.Path(run_dir) / f"{name}.json"


def write_record(record: dict, path) -> pathlib.Path:
    """Writes the record as JSON through a temporary file and a rename (atomic on POSIX:
    never a half-written file)."""
    path = pathlib.Path(path)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(record, indent=2) + "\n")
    tmp.replace(path)
    return path


def describe(record: dict, cfg) -> list[str]:
    """Lines for the terminal: the checkpoint, then each run's success overall and per
    mode (a run is labelled with its seed, and its arm in a sweep)."""
    # (n_runs,) per metric: one run's numbers as one-entry rows.
    per_run = {k: np.atleast_1d(v) for k, v in record.items() if k.startswith("eval/")}
    n_modes = len(per_run) - 1
    arms = plots.arm_labels(cfg.sweep)
    lines = [
        f"{cfg.env}: iteration {record['iteration']} ({record['env_steps']:,} env steps), "
        f"{record['episodes_per_mode']} episodes per mode"
    ]
    for r, seed in enumerate(record["seeds"]):
        per_mode = " ".join(f"{per_run[f'eval/success/{k}'][r]:.2f}" for k in range(n_modes))
        label = f"seed {seed}" + (f", {arms[r // cfg.num_seeds]}" if cfg.sweep else "")
        lines.append(f"  {label}: success {per_run['eval/success'][r]:.3f} (modes: {per_mode})")
    return lines


def main(argv=None) -> int:
    """`python -m d2c_jax.evaluate`: exit status 0, or 2 with one `error: ...` line."""
    parser = cli.Parser(  # argparse's own errors as one line (cli.UsageError)
        prog="python -m d2c_jax.evaluate",
        description="Evaluate a trained run's checkpoint as training does (SPEC §7).",
    )
    parser.add_argument("run_dir", help="a run directory written by train.py")
    parser.add_argument(
        "--episodes", type=int, default=None, help="per goal mode (default: the run's own)"
    )
    parser.add_argument(
        "--checkpoint", type=int, default=None, help="iteration to evaluate (default: newest)"
    )
    try:
        args = parser.parse_args(argv)
        record = evaluate_run(args.run_dir, args.episodes, args.checkpoint)
        cfg = runs.read_config(args.run_dir)
        path = record_path(args.run_dir, record, cfg.eval_episodes)
        write_record({"run_dir": str(args.run_dir), **record}, path)
    # OSError: a run directory the record cannot be written into.
    except (cli.UsageError, runs.RunError, OSError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    print("\n".join(describe(record, cfg)))
    print(f"wrote {path}")
    return 0
