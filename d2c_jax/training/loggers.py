"""Optional logging sinks beside metrics.jsonl: TensorBoard and Weights & Biases.

    python train.py --env medium_maze --log tensorboard          # events under RUN_DIR/tensorboard
    python train.py --env medium_maze --log wandb --wandb-project d2c   # offline, RUN_DIR/wandb

`metrics.jsonl` is always written (resume and the plots read it); a sink gets the same
rows. Every run of the run axis (seeds, sweep arms) is its own series, named by
`series_names`, with env steps as the step. At evaluation rows a sink also gets the
success and curriculum plots as images (the PNGs the loop has just drawn into
RUN_DIR/plots).

Resume: a resumed run recomputes the iterations after its last checkpoint, bitwise as
the killed run computed them (the same seed gives the same run). A sink therefore skips
every row at or below the last step it already holds (`loggers.json` in the run directory
records it after each row), so no series gets a step twice; wandb reopens the same run ids.

This module imports neither package at import time: `missing_extra` names what is
absent before anything compiles, and a sink imports its package when it is opened.
"""

from __future__ import annotations

import dataclasses
import importlib.util
import json
import pathlib
import uuid
from typing import Protocol

import numpy as np

from d2c_jax import config as config_lib
from d2c_jax.training import logging as logging_lib
from d2c_jax.viewing import plots

LOGGER_NAMES: tuple[str, ...] = ("tensorboard", "wandb")

# sink -> (the module it imports, the pip command that installs it).
_EXTRAS: dict[str, tuple[str, str]] = {
    "tensorboard": ("tensorboardX", "pip install 'd2c_jax[log]' (or: pip install tensorboardX)"),
    "wandb": ("wandb", "pip install 'd2c_jax[log]' (or: pip install wandb)"),
}

# The plots sent as images at evaluation rows (files of RUN_DIR/plots, `runs.write_plots`).
EVAL_IMAGES: tuple[str, ...] = ("success", "curriculum")


@dataclasses.dataclass(frozen=True)
class LoggerOptions:
    """The sinks a run logs to besides metrics.jsonl (command-line options, not config:
    a run resumed with other sinks is the same run)."""

    names: tuple[str, ...] = ()
    """Sinks from LOGGER_NAMES."""
    wandb_project: str = "d2c_jax"
    """W&B project name."""
    wandb_name: str | None = None
    """W&B run name (default: the run directory's name); several runs add their series."""


def missing_extra(names: tuple[str, ...]) -> str | None:
    """A one-line message naming the first sink whose package is not installed and the
    pip command that installs it, else None."""
    for name in names:
        module, command = _EXTRAS[name]
        if importlib.util.find_spec(module) is None:
            return f"--log {name} needs the {module} package, which is not installed: {command}"
    return None


def series_names(cfg: config_lib.TrainConfig) -> list[str]:
    """One name per run of the run axis, in run order: 'seed<S>', or with a sweep
    '<arm label>-seed<S>' (e.g. 'diversity_weight=0-seed1'); safe as a directory name."""
    seeds = [cfg.seed + r for r in range(cfg.num_seeds)]
    if not cfg.sweep:
        return [f"seed{s}" for s in seeds]
    arms = [label.replace(", ", "_").replace("/", "_") for label in plots.arm_labels(cfg.sweep)]
    return [f"{arm}-seed{s}" for arm in arms for s in seeds]


def run_scalars(row: dict, run: int, n_runs: int) -> dict[str, float]:
    """The scalar metrics of run `run` in one metrics row.

    Args:
      row: a metrics row (`to_jsonable` values): a number for one run or for a quantity
        shared by every run (iteration, time/*), else a list with one entry per run.
      run, n_runs: the run's index on the run axis and the axis' length.

    Returns:
      {key: float}: per-run lists picked at `run`; arrays (curriculum/goals) left out.
    """
    out = {}
    for key, value in row.items():
        arr = np.asarray(value, np.float64) if not isinstance(value, str) else None
        if arr is None:
            continue
        if arr.ndim == 0:
            out[key] = float(arr)
        elif n_runs > 1 and arr.shape == (n_runs,):
            out[key] = float(arr[run])
    return out


class Sink(Protocol):
    """One logging backend: a series per run."""

    def scalars(self, run: int, step: int, values: dict[str, float]) -> None: ...

    def images(self, run: int, step: int, images: dict[str, np.ndarray]) -> None: ...

    def close(self) -> None: ...


class TensorBoardSink:
    """tensorboardX event files under RUN_DIR/tensorboard/<series>/ (one writer per run)."""

    def __init__(self, out: pathlib.Path, names: list[str]):
        from tensorboardX import SummaryWriter

        self._writers = [SummaryWriter(str(out / "tensorboard" / name)) for name in names]

    def scalars(self, run: int, step: int, values: dict[str, float]) -> None:
        for key, value in values.items():
            self._writers[run].add_scalar(key, value, global_step=step)
        self._writers[run].flush()

    def images(self, run: int, step: int, images: dict[str, np.ndarray]) -> None:
        for key, image in images.items():  # (H, W, C) uint8
            self._writers[run].add_image(key, image, global_step=step, dataformats="HWC")
        self._writers[run].flush()

    def close(self) -> None:
        for writer in self._writers:
            writer.close()


class WandbSink:
    """One W&B run per run of the run axis, in offline mode unless WANDB_MODE says
    otherwise, its files under RUN_DIR/wandb; the run ids are kept in `ids` so that a
    resumed run reopens the same W&B runs."""

    def __init__(self, out: pathlib.Path, names: list[str], options: LoggerOptions, ids, cfg):
        import os

        import wandb

        group = options.wandb_name or out.name
        mode = os.environ.get("WANDB_MODE", "offline")
        self.ids = list(ids) if ids else [uuid.uuid4().hex[:12] for _ in names]
        self._runs = [
            wandb.init(
                project=options.wandb_project,
                name=group if len(names) == 1 else f"{group}/{name}",
                group=group if len(names) > 1 else None,
                id=run_id,
                dir=str(out),
                mode=mode,
                resume="allow",
                reinit="create_new",
                config=json.loads(_config_json(cfg)),
                settings=wandb.Settings(silent=True, console="off"),
            )
            for name, run_id in zip(names, self.ids, strict=True)
        ]

    def scalars(self, run: int, step: int, values: dict[str, float]) -> None:
        self._runs[run].log(values, step=step)

    def images(self, run: int, step: int, images: dict[str, np.ndarray]) -> None:
        import wandb

        self._runs[run].log({k: wandb.Image(v) for k, v in images.items()}, step=step)

    def close(self) -> None:
        for run in self._runs:
            run.finish()


def _config_json(cfg) -> str:
    from d2c_jax.training import runs

    return runs.config_to_json(cfg)


def read_png(path: pathlib.Path) -> np.ndarray:
    """(H, W, 3) uint8 pixels of a PNG file."""
    from PIL import Image

    with Image.open(path) as image:
        return np.asarray(image.convert("RGB"))


class Loggers:
    """The run's optional sinks: rows in, one series per run out, no step twice.

    `progress_path` (RUN_DIR/loggers.json) holds, per sink, the last env step written and
    W&B's run ids; it is rewritten atomically after each row.
    """

    def __init__(self, out, cfg: config_lib.TrainConfig, options: LoggerOptions, n_runs: int):
        self.out, self.n_runs = pathlib.Path(out), n_runs
        self.progress_path = self.out / "loggers.json"
        self.progress = _read_progress(self.progress_path)
        names = series_names(cfg)
        self.sinks: dict[str, Sink] = {}
        for name in options.names:
            state = self.progress.setdefault(name, {"last_step": -1})
            if name == "tensorboard":
                self.sinks[name] = TensorBoardSink(self.out, names)
            else:
                sink = WandbSink(self.out, names, options, state.get("ids"), cfg)
                state["ids"] = sink.ids
                self.sinks[name] = sink
        self._write_progress()

    def write(self, row: dict) -> None:
        """Sends one metrics row (after metrics.jsonl has it) to every sink; at an
        evaluation row, also the plots of RUN_DIR/plots named in EVAL_IMAGES."""
        step = int(row["env_steps"])
        clean = {k: logging_lib.to_jsonable(v) for k, v in row.items()}
        images = {}
        if "eval/success" in row:
            files = {k: self.out / "plots" / f"{k}.png" for k in EVAL_IMAGES}
            images = {f"plots/{k}": read_png(p) for k, p in files.items() if p.is_file()}
        for name, sink in self.sinks.items():
            if step <= self.progress[name]["last_step"]:
                continue  # written before a kill; the resumed run recomputed it equal
            for run in range(self.n_runs):
                sink.scalars(run, step, run_scalars(clean, run, self.n_runs))
                if images:
                    sink.images(run, step, images)
            self.progress[name]["last_step"] = step
        self._write_progress()

    def close(self) -> None:
        for sink in self.sinks.values():
            sink.close()

    def _write_progress(self) -> None:
        tmp = self.progress_path.with_suffix(".json.tmp")
        tmp.write_text(json.dumps(self.progress, indent=1, sort_keys=True))
        tmp.replace(self.progress_path)  # atomic on POSIX


def _read_progress(path: pathlib.Path) -> dict:
    """loggers.json, or {} when there is none (a fresh run) or it is unreadable."""
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return {}
