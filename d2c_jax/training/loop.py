"""The host side of training: run directory, checkpoints, signals, metrics, progress, plots.

Everything on the device is one jitted iteration (`trainer.make_train_step`); this loop
only calls it, evaluates, logs, checkpoints and draws. A run directory holds
`config.json`, `metrics.jsonl`, `checkpoints/` and `plots/`.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import pathlib
import signal
import time

import jax
import numpy as np
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

from d2c_jax.training import checkpoint as checkpoint_lib
from d2c_jax.training import logging as logging_lib


class RunError(Exception):
    """A run that cannot start or must stop; `status` is the process exit status."""

    def __init__(self, message: str, status: int):
        super().__init__(message)
        self.status = status


# --- run directory ------------------------------------------------------------------


def config_to_json(cfg) -> str:
    """The config as pretty JSON (tuples become lists)."""
    return json.dumps(dataclasses.asdict(cfg), indent=2, sort_keys=True)


def prepare_run_dir(out: pathlib.Path, cfg, resume: bool) -> None:
    """Creates or checks the run directory and writes config.json (before any compile).

    Raises:
      RunError(2): a non-empty directory without --resume, --resume with nothing to
        resume, or --resume with a different config; or a directory that cannot be
        created, is not a directory, or cannot be written or read (the OSError's reason).
    """
    out = pathlib.Path(out)
    config_path = out / "config.json"
    if out.exists() and not out.is_dir():
        raise RunError(f"--out {out}: not a directory", 2)
    if resume:
        if not config_path.is_file():
            raise RunError(f"nothing to resume: {out} has no config.json", 2)
        with _run_dir_errors(out, "read config.json"):
            try:
                saved = json.loads(config_path.read_text())
            except ValueError:
                raise RunError(f"--out {out}: config.json is not valid JSON", 2) from None
        current = json.loads(config_to_json(cfg))
        saved.pop("total_steps", None), current.pop("total_steps", None)
        if saved != current:
            diff = sorted(k for k in current if saved.get(k) != current[k])
            raise RunError(f"--resume with a config that differs from {config_path} in {diff}", 2)
    else:
        with _run_dir_errors(out, "read the run directory"):
            if out.exists() and any(out.iterdir()):
                raise RunError(
                    f"run directory {out} is not empty; use --resume or another --out", 2
                )
    with _run_dir_errors(out, "create the run directory"):
        out.mkdir(parents=True, exist_ok=True)
        (out / "plots").mkdir(exist_ok=True)
    with _run_dir_errors(out, "write config.json"):
        config_path.write_text(config_to_json(cfg))


@contextlib.contextmanager
def _run_dir_errors(out: pathlib.Path, action: str):
    """Turns an OSError into RunError(2): '--out DIR: cannot ACTION: REASON (PATH)'."""
    try:
        yield
    except OSError as err:
        reason = err.strerror or type(err).__name__
        where = f" ({err.filename})" if err.filename and str(err.filename) != str(out) else ""
        raise RunError(f"--out {out}: cannot {action}: {reason}{where}", 2) from None


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


def open_checkpointer(out: pathlib.Path) -> checkpoint_lib.Checkpointer:
    """The run's checkpointer (keeps the last 3)."""
    return checkpoint_lib.Checkpointer(out / "checkpoints", max_to_keep=3)


def restore_or_fail(ckpt: checkpoint_lib.Checkpointer, like, out: pathlib.Path):
    """(iteration, state) of the newest checkpoint; RunError(2) when none or unreadable."""
    step = ckpt.latest_step()
    if step is None:
        raise RunError(f"nothing to resume: no checkpoint in {out / 'checkpoints'}", 2)
    try:
        return step, ckpt.restore(step, like)
    except checkpoint_lib.CheckpointError as err:
        raise RunError(str(err), 2) from None


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
