"""Run directories: what `train.py --out DIR` writes, and reading it back.

A run directory holds `config.json`, `metrics.jsonl`, `checkpoints/` and `plots/`. This
module creates and checks one (before anything compiles), opens its checkpoints, loads a
trained run (config, env, newest state) and draws its plots. The commands that read runs
(`python -m d2c_jax.render`, `python -m d2c_jax.plots`) are `training.commands`.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import pathlib

import jax

import envs
from d2c_jax import config as config_lib
from d2c_jax import config_io
from d2c_jax.training import agent as agent_lib
from d2c_jax.training import checkpoint as checkpoint_lib
from d2c_jax.training import logging as logging_lib
from d2c_jax.training import placement
from d2c_jax.viewing import plots


class RunError(Exception):
    """A run that cannot start or must stop; `status` is the process exit status."""

    def __init__(self, message: str, status: int):
        super().__init__(message)
        self.status = status


# --- run directory ------------------------------------------------------------------


def config_to_json(cfg) -> str:
    """The config as pretty JSON (tuples become lists)."""
    return json.dumps(dataclasses.asdict(cfg), indent=2, sort_keys=True)


# Fields a resumed run may change: where it stops and when it saves, not what it computes.
RESUME_MAY_CHANGE = ("total_steps", "checkpoint_every", "checkpoint_minutes")


def prepare_run_dir(out: pathlib.Path, cfg, resume: bool) -> None:
    """Creates or checks the run directory and writes config.json (before any compile).

    Raises:
      RunError(2): a non-empty directory without --resume, --resume with nothing to
        resume, or --resume with a config that differs in more than
        `RESUME_MAY_CHANGE`; or a directory that cannot be created, is not a directory,
        or cannot be written or read (the OSError's reason).
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
        # Through from_dict, so a config.json of an older version (fields since added or
        # re-expressed, e.g. checkpoint_every in iterations) compares by meaning.
        saved = json.loads(config_to_json(config_io.from_dict(config_lib.TrainConfig, saved)))
        current = json.loads(config_to_json(cfg))
        for field in RESUME_MAY_CHANGE:
            saved.pop(field, None), current.pop(field, None)
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


# --- checkpoints ------------------------------------------------------------------------


def checkpoint_dir(out: pathlib.Path, layout: placement.RunLayout | None = None) -> pathlib.Path:
    """Where this process keeps its runs' checkpoints: `checkpoints/`, or with several
    processes `checkpoints/process-<p>-of-<P>/` (each process saves only its own runs)."""
    if layout is None or layout.n_processes == 1:
        return out / "checkpoints"
    return out / "checkpoints" / f"process-{layout.process_index}-of-{layout.n_processes}"


def open_checkpointer(
    out: pathlib.Path, layout: placement.RunLayout | None = None
) -> checkpoint_lib.Checkpointer:
    """This process's checkpointer (keeps the last 3): orbax's, or with several processes
    each process's own `HostCheckpointer`."""
    if layout is None or layout.n_processes == 1:
        return checkpoint_lib.Checkpointer(checkpoint_dir(out, layout), max_to_keep=3)
    return checkpoint_lib.HostCheckpointer(checkpoint_dir(out, layout), max_to_keep=3)


def layout_path(out: pathlib.Path) -> pathlib.Path:
    """Where a run records how its checkpoints split the run axis."""
    return out / "checkpoints" / "layout.json"


def record_layout(out: pathlib.Path, layout: placement.RunLayout, write: bool) -> None:
    """Checks `checkpoints/layout.json` against this job, or (with `write`: process 0)
    writes it when there is none: the processes and the rows each holds (its runs
    padded to its devices), which loading the checkpoints needs.

    Raises:
      RunError(2): resuming checkpoints written by another number of processes or rows
        per process (other devices): their states do not fit this job's.
    """
    path = layout_path(out)
    record = {"n_processes": layout.n_processes, "rows_per_process": layout.local_size}
    if path.is_file():
        saved = _read_layout(path)
        if saved != record:
            raise RunError(
                f"--resume: the checkpoints of {out} hold {saved['n_processes']} process(es) "
                f"x {saved['rows_per_process']} runs (padded to their devices), this job "
                f"{record['n_processes']} x {record['rows_per_process']}; resume with the "
                "processes and devices per process that wrote them",
                2,
            )
        return
    if not write:
        return
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(record))
    tmp.replace(path)


def _read_layout(path: pathlib.Path) -> dict:
    """The record of `record_layout`; RunError(2) when it is unreadable."""
    try:
        saved = json.loads(path.read_text())
        return {
            "n_processes": int(saved["n_processes"]),
            "rows_per_process": int(saved["rows_per_process"]),
        }
    except (OSError, ValueError, KeyError, TypeError):
        raise RunError(f"cannot read checkpoint layout {path}: not a layout record", 2) from None


def saved_layout(out: pathlib.Path, n_runs: int) -> placement.RunLayout:
    """The layout the checkpoints of `out` were written with, seen from process 0 (one
    process holding every run when there is no record: runs before sweeps)."""
    path = layout_path(out)
    if not path.is_file():
        return placement.RunLayout(n_runs, 1, 0, n_runs)
    saved = _read_layout(path)
    # As many "devices" as rows: every process's rows are its share plus padding.
    rows = saved["rows_per_process"]
    return placement.RunLayout(n_runs, saved["n_processes"], 0, rows)


def save_state(ckpt: checkpoint_lib.Checkpointer, iteration: int, ts) -> None:
    """Checkpoints a TrainState without its hyperparameters: they are the config's
    (config.json), so a resumed run takes them from there, and a state of an older
    version whose hyperparameters were fewer still restores."""
    ckpt.save(iteration, ts.replace(hparams=None))


def restore_or_fail(
    ckpt: checkpoint_lib.Checkpointer, like, out: pathlib.Path, layout=None, step=None
) -> tuple[int, object]:
    """(iteration, state) of the checkpoint at `step` (default: the newest; with several
    processes: the newest that every process has), restored into `like`'s shapes and
    shardings with `like`'s hyperparameters, on `like`'s devices; RunError(2) when none
    or unreadable."""
    if step is None:
        step = ckpt.latest_step()
        if layout is not None:
            step = placement.min_over_processes(layout, -1 if step is None else step)
            step = None if step < 0 else step
    if step is None:
        raise RunError(f"nothing to resume: no checkpoint in {checkpoint_dir(out, layout)}", 2)
    try:
        stored_like = like.replace(hparams=None)
        restored = ckpt.restore(step, stored_like)
    except checkpoint_lib.CheckpointError as err:
        raise RunError(str(err), 2) from None
    # On the devices (and shardings) of `like`: a no-op where orbax restored them there.
    restored = jax.tree.map(lambda x, y: jax.device_put(x, y.sharding), restored, stored_like)
    return step, restored.replace(hparams=like.hparams)


# --- trained runs -----------------------------------------------------------------------


def read_config(run_dir) -> config_lib.TrainConfig:
    """The config of a run directory (its config.json).

    Raises:
      RunError(2): no config.json, or one that is not valid JSON.
    """
    run_dir = pathlib.Path(run_dir)
    config_path = run_dir / "config.json"
    if not config_path.is_file():
        raise RunError(f"{run_dir} is not a run directory: no config.json", 2)
    try:
        values = json.loads(config_path.read_text())
    except ValueError:
        raise RunError(f"{config_path} is not valid JSON", 2) from None
    return config_io.from_dict(config_lib.TrainConfig, values)


def load_run(run_dir, step: int | None = None):
    """(cfg, env, ts) of a run directory: config.json and the checkpoint at iteration
    `step` (default: the newest) of every process that wrote one, on this process's
    first device (`restore_runs`).

    ts is the TrainState with a leading run axis (arms x seeds, run order; padding rows
    dropped).

    Raises:
      RunError(2): no config.json, no checkpoint (at `step`), or an unreadable one.
    """
    cfg = read_config(run_dir)
    env = envs.make(cfg.env)
    return cfg, env, restore_runs(agent_lib.Agent(cfg, env), run_dir, step)[1]


def load_one_run(run_dir, seed_index: int, step: int | None = None):
    """(cfg, env, ts) of run `seed_index` of a run directory (`load_run`), ts without the
    run axis.

    Raises:
      RunError(2): as `load_run`, or `seed_index` outside the directory's runs (jax
        indexing would clamp it to a wrong run).
    """
    cfg, env, ts = load_run(run_dir, step)
    check_seed_index(seed_index, len(ts.env_steps), run_dir)
    return cfg, env, jax.tree.map(lambda x: x[seed_index], ts)


def check_seed_index(seed_index: int, n_runs: int, run_dir) -> None:
    """Raises RunError(2) unless run `seed_index` exists among the `n_runs` runs of
    `run_dir`: jax indexing would clamp an index past them to the last run, silently."""
    if not 0 <= seed_index < n_runs:
        raise RunError(f"--seed-index must be in [0, {n_runs}) for {run_dir}, got {seed_index}", 2)


def checkpoint_steps(run_dir, n_runs: int) -> list[int]:
    """The iterations, oldest first, with a checkpoint of every process that wrote the
    checkpoints of `run_dir` (a run of `n_runs` runs); the checkpointer keeps the last 3."""
    run_dir = pathlib.Path(run_dir)
    saved = saved_layout(run_dir, n_runs)
    common = None
    for p in range(saved.n_processes):
        ckpt = open_checkpointer(run_dir, dataclasses.replace(saved, process_index=p))
        try:
            steps = set(ckpt.all_steps())
        finally:
            ckpt.close()
        common = steps if common is None else common & steps
    return sorted(common)


def restore_runs(agent: agent_lib.Agent, run_dir, step: int | None = None):
    """(iteration, ts): every run's state at iteration `step` (default: the newest that
    every process checkpointed), gathered from the processes' checkpoints on this
    process's first device; ts has a leading run axis (run order, no padding rows).

    Raises:
      RunError(2): no checkpoint, none at `step` (the message lists those there are),
        or an unreadable one.
    """
    run_dir = pathlib.Path(run_dir)
    available = checkpoint_steps(run_dir, agent.num_runs)
    if not available:
        raise RunError(f"{run_dir} has no checkpoint (in {checkpoint_dir(run_dir)})", 2)
    if step is None:
        step = available[-1]
    elif step not in available:
        listed = ", ".join(map(str, available))
        raise RunError(
            f"{run_dir} has no checkpoint of iteration {step}; it has iterations {listed}", 2
        )
    saved = saved_layout(run_dir, agent.num_runs)
    parts = []
    for p in range(saved.n_processes):
        layout = dataclasses.replace(saved, process_index=p)
        ckpt = open_checkpointer(run_dir, layout)
        try:
            like = agent.init_runs(layout.local_run_ids())
            parts.append(restore_or_fail(ckpt, like, run_dir, step=step)[1])
        finally:
            ckpt.close()
    rows = jax.numpy.asarray(saved.gathered_rows())
    return step, jax.tree.map(lambda *xs: jax.numpy.concatenate(xs)[rows], *parts)


def write_plots(out: pathlib.Path, env, names: tuple[str, ...] | None = None) -> None:
    """The run's plots from its metrics.jsonl: success per mode, curriculum goals over the
    map (paper Fig. 8), curriculum distance and, for several runs (a sweep or
    num_seeds > 1), eval success per sweep arm (sweep_success.png).

    `names` draws only those of "success", "curriculum" (the live plots the loggers send
    at evaluation rows); None draws all.
    """
    rows = logging_lib.read_metrics(out / "metrics.jsonl")
    if names is None or "success" in names:
        plots.success_curve(rows, env.n_modes, out / "plots" / "success.png")
    if names is None or "curriculum" in names:
        plots.curriculum_snapshots(rows, env, out / "plots" / "curriculum.png")
    if names is not None:
        return
    plots.metric_curve(rows, "curriculum/distance", out / "plots" / "curriculum_distance.png")
    cfg = read_config(out)
    sweep = getattr(cfg, "sweep", ())  # a config from before sweeps: one arm
    if sweep or cfg.num_seeds > 1:
        path = out / "plots" / "sweep_success.png"
        plots.sweep_success_curves(rows, sweep, cfg.num_seeds, path)
