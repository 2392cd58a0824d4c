"""Where the runs of the run axis live: processes, devices and padding (issue 13).

The run axis holds R = arms x seeds runs (`d2c_jax.training.sweep`). Each of the P
processes (hosts, joined by `jax.distributed`) takes a contiguous share of ceil(R / P)
runs and spreads it over its D local devices: the share is padded to a whole number of
runs per device with copies of one of its runs, and the state's leading axis is sharded
over a one-axis mesh of the local devices (`NamedSharding`, `jax.shard_map`). Runs never
talk to each other, so a process needs no other process's state: only the metrics rows
are gathered (`gather_runs`), and each process checkpoints its own runs. Padding runs
are computed and dropped; they never reach an output.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding
from jax.sharding import PartitionSpec as P

RUN_AXIS = "runs"


@dataclasses.dataclass(frozen=True)
class RunLayout:
    """The runs of one process and how the processes' rows line up."""

    n_runs: int  # R, the real runs of the whole sweep
    n_processes: int  # P
    process_index: int  # this process, in [0, P)
    n_local_devices: int  # D, devices of this process

    @property
    def share(self) -> int:
        """Real runs per process (the last ones may hold fewer)."""
        return math.ceil(self.n_runs / self.n_processes)

    @property
    def local_size(self) -> int:
        """Rows of this process's state: its share padded to a multiple of D (>= D).
        Equal for every process, so the gathered rows line up."""
        return max(1, math.ceil(self.share / self.n_local_devices)) * self.n_local_devices

    @property
    def runs_per_device(self) -> int:
        return self.local_size // self.n_local_devices

    def local_runs(self, process: int | None = None) -> range:
        """The real runs of `process` (default: this one), a contiguous range."""
        p = self.process_index if process is None else process
        return range(min(p * self.share, self.n_runs), min((p + 1) * self.share, self.n_runs))

    def local_run_ids(self) -> np.ndarray:
        """(local_size,) int: the run of each row of this process's state; the padding
        rows repeat its first run (run 0 for a process without runs)."""
        real = list(self.local_runs())
        filler = real[0] if real else 0
        return np.asarray(real + [filler] * (self.local_size - len(real)), np.int64)

    def gathered_rows(self) -> np.ndarray:
        """(R,) int: the rows of the processes' stacked states (P * local_size rows,
        process after process) that hold runs 0..R-1, in run order."""
        return np.concatenate(
            [
                p * self.local_size + np.arange(len(self.local_runs(p)))
                for p in range(self.n_processes)
            ]
        ).astype(np.int64)


def make_layout(n_runs: int) -> RunLayout:
    """The layout of `n_runs` runs over this job's processes and local devices."""
    return RunLayout(
        n_runs=n_runs,
        n_processes=jax.process_count(),
        process_index=jax.process_index(),
        n_local_devices=jax.local_device_count(),
    )


def run_mesh(layout: RunLayout) -> Mesh | None:
    """A one-axis mesh over this process's devices, or None with one device (nothing
    to shard: the program stays exactly the single-device one)."""
    if layout.n_local_devices == 1:
        return None
    return Mesh(np.asarray(jax.local_devices()), (RUN_AXIS,))


def place(tree, mesh: Mesh | None):
    """Every leaf (leading run axis) sharded over the mesh's devices; as is without one."""
    if mesh is None:
        return tree
    return jax.device_put(tree, NamedSharding(mesh, P(RUN_AXIS)))


def shard_runs(fn, mesh: Mesh | None):
    """`fn` (leading run axis on every argument and output) run blockwise on each device
    of the mesh: `jax.shard_map` with every operand split on the run axis. Runs are
    independent, so no device ever needs another's block. Without collectives there is
    nothing for shard_map's varying-axis check to protect, and it would reject the
    constants that some `lax.cond` branches return, so it is off."""
    if mesh is None:
        return fn
    return jax.shard_map(
        fn, mesh=mesh, in_specs=P(RUN_AXIS), out_specs=P(RUN_AXIS), check_vma=False
    )


def gather_runs(tree, layout: RunLayout):
    """Host numpy leaves with the real runs 0..R-1 on the leading axis, in run order:
    this process's rows, or with several processes everyone's (every process gets all).

    With P > 1 this is a collective: every process must call it at the same point.
    """
    tree = _every_process(layout, jax.device_get(tree))
    rows = layout.gathered_rows()
    return jax.tree.map(lambda x: np.asarray(x)[rows], tree)


def _every_process(layout: RunLayout, tree):
    """Every process's leaves (leading axis) concatenated process after process; as is
    with one process. With several it is a collective (`process_allgather`)."""
    if layout.n_processes == 1:
        return tree
    from jax.experimental import multihost_utils

    return multihost_utils.process_allgather(tree, tiled=True)


def any_process(layout: RunLayout, flag: bool) -> bool:
    """Whether `flag` is set in any process (a collective with several processes), so
    that all of them stop at the same iteration."""
    return bool(np.asarray(_every_process(layout, np.asarray([flag]))).any())


def min_over_processes(layout: RunLayout, value: int) -> int:
    """The smallest of every process's `value` (a collective with several processes)."""
    return int(np.asarray(_every_process(layout, np.asarray([value]))).min())


def sync_processes(layout: RunLayout, name: str) -> None:
    """Waits until every process reaches the point called `name` (no-op for one)."""
    if layout.n_processes > 1:
        from jax.experimental import multihost_utils

        multihost_utils.sync_global_devices(name)


# --- memory -------------------------------------------------------------------------------


def state_bytes(init, hp) -> int:
    """Bytes of one run's state: `init(key, hp)`'s output shapes, abstractly evaluated
    (nothing is allocated or compiled). A PRNG key counts as its two uint32 words."""
    shapes = jax.eval_shape(init, jax.random.key(0), hp)
    total = 0
    for leaf in jax.tree.leaves(shapes):
        if jax.dtypes.issubdtype(leaf.dtype, jax.dtypes.prng_key):
            total += 8 * math.prod(leaf.shape)
        else:
            total += leaf.dtype.itemsize * math.prod(leaf.shape)
    return total


def available_host_bytes() -> int | None:
    """RAM available to new allocations (Linux `MemAvailable`), or None where unknown."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        return None
    return None


def device_memory_bytes(device) -> int | None:
    """An accelerator's free memory for new buffers, or None where it does not say."""
    stats = device.memory_stats() or {}
    if "bytes_limit" not in stats:
        return None
    return stats["bytes_limit"] - stats.get("bytes_in_use", 0)


# --- processes ----------------------------------------------------------------------------


def initialize_processes(
    coordinator: str | None, num_processes: int | None, process_id: int | None
) -> None:
    """Joins this process to a multi-process job with JAX's distributed runtime.

    With a coordinator address, the process count and this process's id come from the
    arguments; with none, `jax.distributed.initialize` reads them from the cluster
    scheduler (SLURM, Open MPI, ...). Cross-process collectives between CPU devices use
    gloo (the setting concerns only the CPU backend; accelerators keep their own).
    """
    jax.config.update("jax_cpu_collectives_implementation", "gloo")
    jax.distributed.initialize(
        coordinator_address=coordinator, num_processes=num_processes, process_id=process_id
    )
