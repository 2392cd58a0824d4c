"""Checkpoints of the whole training state with orbax (host side).

Orbax writes each checkpoint into a temporary directory and renames it when complete,
so a run killed mid-write never leaves a half checkpoint that looks valid; the last
`max_to_keep` are kept. Typed PRNG keys are stored as their raw key data.
"""

from __future__ import annotations

import contextlib
import logging
import pathlib

import jax
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
