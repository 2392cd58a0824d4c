"""Checkpoints of the whole training state with orbax (host side).

Orbax writes each checkpoint into a temporary directory and renames it when complete,
so a run killed mid-write never leaves a half checkpoint that looks valid; the last
`max_to_keep` are kept. Typed PRNG keys are stored as their raw key data.
"""

from __future__ import annotations

import contextlib
import logging
import os
import pathlib

import jax
import numpy as np
import orbax.checkpoint as ocp

# orbax logs every save at INFO; the trainer reports checkpoints itself.
logging.getLogger("absl").setLevel(logging.WARNING)


class CheckpointError(Exception):
    """A checkpoint is missing or cannot be read."""


@contextlib.contextmanager
def _quiet_orbax():
    """Silences orbax's own error logs: a broken checkpoint is reported once, by us."""
    absl_logger = logging.getLogger("absl")
    level = absl_logger.level
    absl_logger.setLevel(logging.CRITICAL)
    try:
        yield
    finally:
        absl_logger.setLevel(level)


def _is_key(x) -> bool:
    return hasattr(x, "dtype") and jax.dtypes.issubdtype(x.dtype, jax.dtypes.prng_key)


def _to_storable(tree):
    """Replaces typed PRNG keys by their uint32 key data."""
    return jax.tree.map(lambda x: jax.random.key_data(x) if _is_key(x) else x, tree)


def _from_storable(stored, like):
    """Inverse of `_to_storable`, using `like` to know which leaves were keys."""
    return jax.tree.map(lambda s, t: jax.random.wrap_key_data(s) if _is_key(t) else s, stored, like)


class Checkpointer:
    """Saves and restores a pytree at integer steps under `directory`."""

    def __init__(self, directory: str | pathlib.Path, max_to_keep: int = 3):
        self.directory = pathlib.Path(directory).absolute()
        options = ocp.CheckpointManagerOptions(max_to_keep=max_to_keep, create=True)
        with _quiet_orbax():
            self._manager = ocp.CheckpointManager(self.directory, options=options)

    def latest_step(self) -> int | None:
        """The newest complete checkpoint's step, or None."""
        with _quiet_orbax():
            return self._manager.latest_step()

    def all_steps(self) -> list[int]:
        """The steps of every complete checkpoint kept, oldest first."""
        with _quiet_orbax():
            return sorted(self._manager.all_steps())

    def save(self, step: int, tree) -> None:
        """Writes `tree` at `step` and waits until it is on disk."""
        self._manager.save(step, args=ocp.args.StandardSave(_to_storable(tree)), force=True)
        self._manager.wait_until_finished()

    def restore(self, step: int, like):
        """Reads the checkpoint at `step` into the structure, shapes and dtypes of `like`.

        Raises:
          CheckpointError: if it is missing, unreadable or of another structure.
        """
        abstract = jax.tree.map(ocp.utils.to_shape_dtype_struct, _to_storable(like))
        try:
            with _quiet_orbax():
                stored = self._manager.restore(step, args=ocp.args.StandardRestore(abstract))
        except Exception as err:  # orbax raises many types; all mean "unreadable"
            first_line = str(err).splitlines()[0] if str(err) else type(err).__name__
            if "tree structures do not match" in first_line:
                first_line = (
                    "its state has another layout (written by another version of d2c_jax, "
                    "e.g. one before the issue-16 restructure; resume it with that version)"
                )
            raise CheckpointError(
                f"cannot read checkpoint {self.directory / str(step)}: {first_line}"
            ) from err
        return _from_storable(stored, like)

    def close(self) -> None:
        """Finishes pending writes."""
        self._manager.close()


class HostCheckpointer:
    """`Checkpointer`'s interface for one process of a multi-process job: its own runs'
    state as one .npz file per step, in host memory.

    Orbax coordinates every save across all processes of a job (its signals and
    metadata merges are keyed by step, not by directory), which process-local arrays
    saved by each process on its own do not fit. Each file is written under a temporary
    name and renamed when complete (atomic on POSIX), so a killed save leaves the last
    complete step; the last `max_to_keep` are kept.
    """

    def __init__(self, directory: str | pathlib.Path, max_to_keep: int = 3):
        self.directory = pathlib.Path(directory).absolute()
        self.directory.mkdir(parents=True, exist_ok=True)
        self.max_to_keep = max_to_keep

    def _path(self, step: int) -> pathlib.Path:
        return self.directory / f"step-{step}.npz"

    def all_steps(self) -> list[int]:
        """The steps of every checkpoint kept, oldest first."""
        names = (p.name for p in self.directory.glob("step-*.npz"))
        return sorted(int(n[len("step-") : -len(".npz")]) for n in names)

    def latest_step(self) -> int | None:
        steps = self.all_steps()
        return steps[-1] if steps else None

    def save(self, step: int, tree) -> None:
        leaves = jax.tree.leaves(jax.device_get(_to_storable(tree)))
        tmp = self.directory / f".step-{step}.npz.tmp"
        with open(tmp, "wb") as f:
            np.savez(f, *leaves)
            f.flush()
            os.fsync(f.fileno())
        tmp.replace(self._path(step))
        for old in self.all_steps()[: -self.max_to_keep]:
            self._path(old).unlink(missing_ok=True)

    def restore(self, step: int, like):
        """The state at `step` as host arrays in the structure of `like` (shapes and
        dtypes checked leaf by leaf).

        Raises:
          CheckpointError: if it is missing, unreadable or of another layout.
        """
        path = self._path(step)
        storable = _to_storable(like)
        treedef = jax.tree.structure(storable)
        try:
            with np.load(path) as stored:
                leaves = [stored[f"arr_{i}"] for i in range(len(stored.files))]
        except (OSError, ValueError, KeyError) as err:
            raise CheckpointError(f"cannot read checkpoint {path}: {err}") from err
        wanted = [(tuple(x.shape), np.dtype(x.dtype)) for x in jax.tree.leaves(storable)]
        if [(x.shape, x.dtype) for x in leaves] != wanted:
            raise CheckpointError(
                f"cannot read checkpoint {path}: its state has another layout (written by "
                "another version of d2c_jax, or with other settings)"
            )
        return _from_storable(jax.tree.unflatten(treedef, leaves), like)

    def close(self) -> None:
        """Nothing pending: saves are synchronous."""
