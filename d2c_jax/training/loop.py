"""The host loop of training: `train()` runs, evaluates, logs, checkpoints and draws.

Everything on the device is one jitted iteration (`agent.jit_step`); this loop only calls
it, evaluates on schedule, writes metrics rows, saves checkpoints, handles stop signals
and draws the plots at the end. The run directory it writes is `d2c_jax.training.runs`'s.
"""

from __future__ import annotations

import contextlib
import pathlib
import signal
import time
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

import envs
from d2c_jax import config as config_lib
from d2c_jax.training import agent as agent_lib
from d2c_jax.training import logging as logging_lib
from d2c_jax.training import runs
from d2c_jax.training.runs import RunError  # noqa: F401  (raised here; the CLI catches it)

# --- signals --------------------------------------------------------------------------


class StopFlag:
    """Set by SIGINT/SIGTERM; the loop checkpoints and exits at the next iteration end."""

    def __init__(self):
        self.signal: int | None = None

    def __call__(self, signum, frame):
        self.signal = signum


@contextlib.contextmanager
def catch_stop_signals():
    """Installs the stop flag for SIGINT and SIGTERM, restoring the handlers afterwards."""
    flag = StopFlag()
    previous = {s: signal.signal(s, flag) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield flag
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)


# --- progress -----------------------------------------------------------------------


def make_progress() -> Progress:
    """A progress bar showing env steps, steps/s and the latest success."""
    return Progress(
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        TextColumn("{task.completed:,.0f}/{task.total:,.0f} env steps"),
        TextColumn("{task.fields[rate]:,.0f} steps/s"),
        TextColumn("success {task.fields[success]}"),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
    )


class ProgressBar:
    """The run's task on a `make_progress` bar (hidden when quiet)."""

    def __init__(self, progress: Progress, name: str, sched, start: int, quiet: bool):
        self.progress, self.sched, self.success = progress, sched, "-"
        self.task = progress.add_task(
            name,
            total=sched.total_iterations * sched.env_steps,
            completed=start * sched.env_steps,
            rate=0.0,
            success="-",
            visible=not quiet,
        )

    def update(self, iteration: int, lap: float, row: dict) -> None:
        """Env steps done, the last iteration's rate and the latest eval success."""
        if "eval/success" in row:
            self.success = f"{logging_lib.mean_of(row['eval/success']):.2f}"
        self.progress.update(
            self.task,
            completed=iteration * self.sched.env_steps,
            rate=self.sched.env_steps / lap,
            success=self.success,
        )


def host_metrics(metrics: dict, num_seeds: int) -> dict:
    """Device metrics (leading seed axis) to host values: scalars for one seed, else lists."""
    metrics = jax.device_get(metrics)
    if num_seeds == 1:
        return {k: np.asarray(v)[0] for k, v in metrics.items()}
    return {k: np.asarray(v) for k, v in metrics.items()}


def check_finite(metrics: dict, iteration: int) -> None:
    """Raises RunError(3) naming the iteration and the first non-finite quantity."""
    bad = logging_lib.first_non_finite(metrics)
    if bad is None and "health/params_finite" in metrics:
        if not np.asarray(metrics["health/params_finite"]).all():
            bad = "parameters (health/params_finite)"
    if bad is not None:
        raise RunError(
            f"non-finite value in {bad} at iteration {iteration}; stopped, the last good "
            "checkpoint is kept",
            3,
        )


class Stopwatch:
    """Wall-clock bookkeeping for the time/* metrics."""

    def __init__(self):
        self.start = time.perf_counter()
        self.last = self.start

    def lap(self) -> float:
        now = time.perf_counter()
        lap, self.last = now - self.last, now
        return lap

    def elapsed(self) -> float:
        return time.perf_counter() - self.start


# --- the loop ---------------------------------------------------------------------------


def train(cfg: config_lib.TrainConfig, out, resume: bool = False, quiet: bool = False) -> int:
    """Runs (or resumes) training into run directory `out`; returns the exit status
    (0, or 128 + the signal that stopped it).

    Raises:
      RunError: bad run directory or checkpoint (status 2), non-finite values (status 3).
    """
    out = pathlib.Path(out)
    env = envs.make(cfg.env)
    runs.prepare_run_dir(out, cfg, resume)  # bad input fails here, before any compile
    agent = agent_lib.Agent(cfg, env)
    if not quiet:
        print(describe(cfg, agent.schedule), flush=True)
    ckpt = runs.open_checkpointer(out)
    try:
        start, ts = _initial_state(agent, ckpt, out, resume)
        clock = Stopwatch()
        # Compiled ahead of time, so time/compile_s is apart from the first iteration.
        steps = _Compiled(
            train=agent_lib.jit_step(agent).lower(ts).compile(),
            evaluate=agent_lib.jit_evaluate(agent).lower(ts, eval_keys(cfg, 0)).compile(),
        )
        with logging_lib.MetricsWriter(out / "metrics.jsonl") as writer:
            status = _iterate(agent, steps, ts, start, ckpt, writer, clock, quiet)
    finally:
        ckpt.close()
    runs.write_plots(out, env)
    return status


class _Compiled(NamedTuple):
    """The compiled programs of a run: train(ts) and evaluate(ts, keys)."""

    train: object
    evaluate: object


def _initial_state(agent: agent_lib.Agent, ckpt, out: pathlib.Path, resume: bool):
    """(iterations done, TrainState): fresh, or the newest checkpoint with metrics.jsonl cut
    back to it."""
    ts = agent.init_seeds()
    metrics_path = out / "metrics.jsonl"
    if not resume:
        metrics_path.unlink(missing_ok=True)
        return 0, ts
    start, ts = runs.restore_or_fail(ckpt, ts, out)
    # A run stopped by a signal evaluated at its last iteration; an uninterrupted run
    # evaluates there only on schedule, so drop an unscheduled evaluation.
    strip = () if is_eval_iteration(start, agent.schedule) else ("eval/", "curriculum/goals")
    logging_lib.truncate_metrics(metrics_path, start, strip_last=strip)
    return start, ts


def _iterate(agent, steps: _Compiled, ts, start: int, ckpt, writer, clock, quiet: bool) -> int:
    """Iterations start..total (or until a stop signal); returns the exit status."""
    cfg, sched = agent.cfg, agent.schedule
    timing = {"time/compile_s": clock.lap()}
    with catch_stop_signals() as stop, make_progress() as progress:
        bar = ProgressBar(progress, cfg.env, sched, start, quiet)
        for it in range(start, sched.total_iterations):
            ts, metrics = steps.train(ts)
            last = it + 1 == sched.total_iterations or stop.signal is not None
            row = host_metrics(metrics, cfg.num_seeds)
            check_finite(row, it + 1)
            if is_eval_iteration(it + 1, sched) or last:
                row.update(_evaluation(steps, ts, cfg, it + 1))
            lap = clock.lap()
            writer.write(_row(it + 1, sched, row, lap, clock, timing))
            if timing and not quiet:  # the first iteration of this process
                left = (sched.total_iterations - it - 1) * lap / 60
                progress.console.print(f"  estimated time to finish: {left:.1f} min")
            timing = {}
            bar.update(it + 1, lap, row)
            if last or (it + 1) % sched.checkpoint_every == 0:
                ckpt.save(it + 1, ts)
            if stop.signal is not None:
                return 128 + stop.signal
    return 0


def _evaluation(steps: _Compiled, ts, cfg: config_lib.TrainConfig, iteration: int) -> dict:
    """The evaluation metrics and the curriculum goals (first seed's for one seed)."""
    row = host_metrics(steps.evaluate(ts, eval_keys(cfg, iteration)), cfg.num_seeds)
    goals = jax.device_get(ts.curriculum_goals)
    row["curriculum/goals"] = goals[0] if cfg.num_seeds == 1 else goals
    return row


def _row(iteration: int, sched, metrics: dict, lap: float, clock, timing: dict) -> dict:
    """One metrics.jsonl row: counters first, then the metrics, then time/*."""
    return {
        "iteration": iteration,
        "env_steps": iteration * sched.env_steps,
        **metrics,
        "time/iteration_s": lap,
        "time/env_steps_per_s": sched.env_steps / lap,
        "time/elapsed_s": clock.elapsed(),
        **timing,
    }


def eval_keys(cfg: config_lib.TrainConfig, iteration: int) -> jax.Array:
    """Evaluation keys per seed, a pure function of (seed, iteration): resume-safe."""
    return jnp.stack(
        [
            jax.random.fold_in(jax.random.key(cfg.seed + i + 10_000), iteration)
            for i in range(cfg.num_seeds)
        ]
    )


def is_eval_iteration(iteration: int, sched: agent_lib.Schedule) -> bool:
    """Scheduled evaluations (the final one is added by the loop)."""
    return iteration % sched.eval_every == 0


def describe(cfg: config_lib.TrainConfig, sched: agent_lib.Schedule) -> str:
    """The run's first lines: env, preset, seeds, device, and the schedule."""
    return (
        f"d2c_jax: env {cfg.env}, preset {cfg.preset}, "
        f"seeds {cfg.seed}..{cfg.seed + cfg.num_seeds - 1}"
        f", device {jax.devices()[0].platform}:{jax.devices()[0].device_kind}\n"
        f"  {sched.total_iterations} iterations x {sched.env_steps} env steps, "
        f"{sched.sac_updates} SAC + {sched.classifier_updates} classifier updates each, "
        f"warm-up {sched.warmup_iterations}, eval every {sched.eval_every}"
    )
