"""brax 0.14.2's trainers on jax 0.10: a stand-in for the removed `jax.device_put_replicated`.

brax's SAC, PPO and APG `train()` (and `brax.training.pmap.bcast_local_devices`) put
their initial training state on the devices with `jax.device_put_replicated`, which jax
0.10 removed: `brax.training.agents.sac.train.train` fails at its first line of setup
with an AttributeError. `install()` defines it again, the way it was documented: the
tree stacked along a new leading device axis, one slice per device, which is the layout
brax's `jax.pmap`-ed epochs take.

This lives here, not in the package: it patches a third-party module's view of jax, which
only the benchmark and the tests that run brax's trainers need (`benchmarks.brax_sac`,
`tests/test_brax_adapter.py`). Drop it once brax no longer calls the removed function.
"""

from __future__ import annotations

from typing import Any, Sequence

import jax
import jax.numpy as jnp
import numpy as np


def device_put_replicated(tree: Any, devices: Sequence[jax.Device]) -> Any:
    """`tree`'s leaves stacked len(devices) times on a new leading axis, slice i on
    devices[i] (the removed jax function's contract): leaves (...) -> (n_devices, ...)."""
    devices = list(devices)
    mesh = jax.sharding.Mesh(np.array(devices), ("devices",))
    sharding = jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec("devices"))
    stacked = jax.tree.map(lambda x: jnp.stack([jnp.asarray(x)] * len(devices)), tree)
    return jax.device_put(stacked, sharding)


def install() -> None:
    """Defines `jax.device_put_replicated` where this jax lacks it (idempotent)."""
    if not hasattr(jax, "device_put_replicated"):
        jax.device_put_replicated = device_put_replicated
