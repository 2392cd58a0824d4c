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
from d2c_jax.training import loggers as loggers_lib
from d2c_jax.training import logging as logging_lib
from d2c_jax.training import placement, programs, runs, sweep
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


def host_metrics(metrics: dict, num_runs: int) -> dict:
    """Host metrics of the real runs (leading run axis) to row values: scalars for one
    run, else arrays with one entry per run."""
    if num_runs == 1:
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


class CheckpointTimer:
    """`checkpoint_minutes`: whether that much wall clock has passed since the last
    checkpoint (or the start), so a run killed without a signal (SIGKILL, a lost machine)
    loses at most about that much work, whatever `checkpoint_every` is."""

    def __init__(self, minutes: float, clock=time.monotonic):
        self.seconds, self.clock = 60.0 * minutes, clock
        self.reset()

    def reset(self) -> None:
        self.last = self.clock()

    def due(self, layout: placement.RunLayout) -> bool:
        """Due in any process (a collective with several), so all of them save together."""
        mine = self.seconds > 0 and self.clock() - self.last >= self.seconds
        return placement.any_process(layout, mine)


# --- the loop ---------------------------------------------------------------------------


def train(
    cfg: config_lib.TrainConfig,
    out,
    resume: bool = False,
    quiet: bool = False,
    log: loggers_lib.LoggerOptions | None = None,
) -> int:
    """Runs (or resumes) training into run directory `out`; returns the exit status
    (0, or 128 + the signal that stopped it).

    `log` names the sinks (TensorBoard, W&B) that get every row besides metrics.jsonl.

    The run axis (arms x seeds) is split over this job's processes and devices
    (`placement`); with several processes, process 0 writes config.json, metrics.jsonl
    and the plots, and every process checkpoints its own runs.

    Raises:
      RunError: bad run directory or checkpoint, or runs that do not fit in memory
        (status 2); non-finite values (status 3).
    """
    out = pathlib.Path(out)
    env = envs.make(cfg.env)
    layout = placement.make_layout(sweep.n_runs(cfg))
    lead = layout.process_index == 0
    quiet = quiet or not lead
    agent = agent_lib.Agent(cfg, env)
    problem = memory_problem(agent, layout)  # before the run directory is made
    if problem:
        raise RunError(problem, 2)
    if lead:
        runs.prepare_run_dir(out, cfg, resume)  # bad input fails here, before any compile
    placement.sync_processes(layout, "run directory ready")
    if not quiet:
        print(describe(cfg, agent.schedule, layout), flush=True)
    mesh = placement.run_mesh(layout)
    runs.record_layout(out, layout, write=False)  # every process refuses a mismatch
    placement.sync_processes(layout, "checkpoint layout checked")
    if lead:
        runs.record_layout(out, layout, write=True)
    ckpt = runs.open_checkpointer(out, layout)
    try:
        start, ts = _initial_state(agent, layout, mesh, ckpt, out, resume)
        clock = Stopwatch()
        # Compiled ahead of time, so time/compile_s is apart from the first iteration.
        n = layout.runs_per_device
        keys = eval_keys(agent, layout, mesh, 0)
        steps = _Compiled(
            train=programs.jit_step(agent, mesh, n).lower(ts).compile(),
            evaluate=programs.jit_evaluate(agent, mesh, n).lower(ts, keys).compile(),
        )
        writer = logging_lib.MetricsWriter(out / "metrics.jsonl") if lead else None
        sinks = None
        if lead and log is not None and log.names:
            sinks = loggers_lib.Loggers(out, cfg, log, layout.n_runs)
        try:
            loop = _Loop(agent, layout, mesh, steps, ckpt, _Output(out, env, writer, sinks), clock)
            status = loop.run(ts, start, quiet)
        finally:
            if writer is not None:
                writer.close()
            if sinks is not None:
                sinks.close()
    finally:
        ckpt.close()
    if lead:
        runs.write_plots(out, env)
    return status


class _Compiled(NamedTuple):
    """The compiled programs of a run: train(ts) and evaluate(ts, keys)."""

    train: object
    evaluate: object


class _Output(NamedTuple):
    """Where the lead process's rows go: metrics.jsonl and the optional sinks (both None
    on the other processes)."""

    out: pathlib.Path
    env: object
    writer: logging_lib.MetricsWriter | None
    sinks: loggers_lib.Loggers | None

    def write(self, row: dict) -> None:
        """metrics.jsonl first (the plots read it), then, at an evaluation row, the live
        success and curriculum plots, then the sinks."""
        if self.writer is None:
            return
        self.writer.write(row)
        if self.sinks is not None:
            if "eval/success" in row:
                runs.write_plots(self.out, self.env, names=loggers_lib.EVAL_IMAGES)
            self.sinks.write(row)


def memory_problem(agent: agent_lib.Agent, layout: placement.RunLayout) -> str | None:
    """A one-line message when this process's runs do not fit in memory, else None.

    Estimated before compiling, from the state's shapes (`placement.state_bytes`):
    on a CPU the runs' states and a checkpoint's host copy of them must fit in the
    available RAM; on an accelerator each device's block of states, with a quarter
    more for the step's temporaries, must fit in that device's memory.
    """
    per_run = placement.state_bytes(agent.init, agent_lib.hyperparams(agent.cfg))
    device = jax.local_devices()[0]
    if device.platform == "cpu":
        need, have = 2 * layout.local_size * per_run, placement.available_host_bytes()
        where = "of RAM"
    else:
        need = 1.25 * layout.runs_per_device * per_run
        have = placement.device_memory_bytes(device)
        where = f"per {device.platform.upper()} device"
    if have is None or need <= have:
        return None
    gib = 2.0**30
    return (
        f"{layout.local_size} runs need about {need / gib:.1f} GiB {where} "
        f"({per_run / gib:.2f} GiB of state per run) but {have / gib:.1f} GiB is available; "
        "use fewer --seeds or sweep values, more devices, or a smaller --replay.capacity"
    )


def _initial_state(agent, layout, mesh, ckpt, out: pathlib.Path, resume: bool):
    """(iterations done, this process's TrainState): fresh, or the newest checkpoint
    every process has, with metrics.jsonl cut back to it."""
    ts = placement.place(agent.init_runs(layout.local_run_ids()), mesh)
    metrics_path = out / "metrics.jsonl"
    lead = layout.process_index == 0
    if not resume:
        if lead:
            metrics_path.unlink(missing_ok=True)
        return 0, ts
    start, ts = runs.restore_or_fail(ckpt, ts, out, layout)
    # A run stopped by a signal evaluated at its last iteration; an uninterrupted run
    # evaluates there only on schedule, so drop an unscheduled evaluation.
    strip = () if is_eval_iteration(start, agent.schedule) else ("eval/", "curriculum/goals")
    if lead:
        logging_lib.truncate_metrics(metrics_path, start, strip_last=strip)
    return start, ts


class _Loop:
    """Iterations of one process: step, gather, evaluate, write, checkpoint."""

    def __init__(self, agent, layout, mesh, steps: _Compiled, ckpt, output: _Output, clock):
        self.agent, self.layout, self.mesh, self.steps = agent, layout, mesh, steps
        self.ckpt, self.output, self.clock = ckpt, output, clock
        self.checkpoint_timer = CheckpointTimer(agent.cfg.checkpoint_minutes)

    def run(self, ts, start: int, quiet: bool) -> int:
        """Iterations start..total (or until a stop signal); returns the exit status."""
        sched, layout = self.agent.schedule, self.layout
        timing = {"time/compile_s": self.clock.lap()}
        with catch_stop_signals() as stop, make_progress() as progress:
            bar = ProgressBar(progress, self.agent.cfg.env, sched, start, quiet)
            for it in range(start, sched.total_iterations):
                ts, metrics = self.steps.train(ts)
                # The step is dispatched asynchronously: the gather below waits for it, so
                # the flag is read after it, and a signal that arrives while this
                # iteration computes stops the run at its end, not one iteration later.
                row = host_metrics(placement.gather_runs(metrics, layout), layout.n_runs)
                check_finite(row, it + 1)
                # Every process must take the same branches (the gathers are collectives).
                stopping = placement.any_process(layout, stop.signal is not None)
                last = it + 1 == sched.total_iterations or stopping
                if is_eval_iteration(it + 1, sched) or last:
                    row.update(self._evaluation(ts, it + 1))
                lap = self.clock.lap()
                self.output.write(_row(it + 1, sched, row, lap, self.clock, timing))
                if timing and not quiet:  # the first iteration of this process
                    left = (sched.total_iterations - it - 1) * lap / 60
                    progress.console.print(f"  estimated time to finish: {left:.1f} min")
                timing = {}
                bar.update(it + 1, lap, row)
                timed = self.checkpoint_timer.due(layout)  # a collective: every iteration
                if last or (it + 1) % sched.checkpoint_every == 0 or timed:
                    runs.save_state(self.ckpt, it + 1, ts)
                    self.checkpoint_timer.reset()
                if stopping:
                    return 128 + (stop.signal or signal.SIGTERM)
        return 0

    def _evaluation(self, ts, iteration: int) -> dict:
        """The evaluation metrics and the curriculum goals of the real runs."""
        keys = eval_keys(self.agent, self.layout, self.mesh, iteration)
        gathered = placement.gather_runs(
            {"eval": self.steps.evaluate(ts, keys), "goals": ts.curriculum_goals}, self.layout
        )
        row = host_metrics(gathered["eval"], self.layout.n_runs)
        goals = gathered["goals"]
        row["curriculum/goals"] = goals[0] if self.layout.n_runs == 1 else goals
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


def eval_keys(agent: agent_lib.Agent, layout: placement.RunLayout, mesh, iteration: int):
    """Evaluation keys of this process's rows, a pure function of (the run's seed,
    iteration): resume-safe, and a sweep arm's equal the single run's."""
    seeds = [agent.run_configs[r].seed for r in layout.local_run_ids()]
    keys = jnp.stack(
        [jax.random.fold_in(jax.random.key(seed + 10_000), iteration) for seed in seeds]
    )
    return placement.place(keys, mesh)


def is_eval_iteration(iteration: int, sched: agent_lib.Schedule) -> bool:
    """Scheduled evaluations (the final one is added by the loop)."""
    return iteration % sched.eval_every == 0


def describe(cfg: config_lib.TrainConfig, sched: agent_lib.Schedule, layout=None) -> str:
    """The run's first lines: env, preset, runs, devices, and the schedule."""
    device = jax.devices()[0]
    runs_line = f"seeds {cfg.seed}..{cfg.seed + cfg.num_seeds - 1}"
    if cfg.sweep:
        fields = ", ".join(sweep.flag_spelling(f) for f, _ in cfg.sweep)
        runs_line += f" x {sweep.n_arms(cfg)} arms ({fields}) = {sweep.n_runs(cfg)} runs"
    where = f"device {device.platform}:{device.device_kind}"
    if layout is not None and (layout.n_processes > 1 or layout.n_local_devices > 1):
        where += (
            f" x {layout.n_local_devices} per process x {layout.n_processes} processes, "
            f"{layout.local_size} runs per process"
        )
    return (
        f"d2c_jax: {cfg.algo}, env {cfg.env}, preset {cfg.preset}, {runs_line}, {where}\n"
        f"  {sched.total_iterations} iterations x {sched.env_steps} env steps, "
        f"{sched.sac_updates} SAC + {sched.classifier_updates} classifier updates each, "
        f"warm-up {sched.warmup_iterations}, eval every {sched.eval_every}"
    )
