"""d2c_jax: D2C outcome-directed curriculum RL end to end in JAX/MJX.

The package has one subpackage per layer, each importing only the layers before it
(`envs/`, the MJX environments, stays apart; docs/LAYOUT.md):

- `core/`: the RL core: networks, SAC, the replay buffer, HER and the episode loop;
- `curricula/`: how goals are chosen: D2C's classifier ensemble and curriculum, and the
  auction matching they share with other curricula;
- `viewing/`: drawing: plots, rendering, the demo;
- `training/`: the agent (one jitted iteration), the host loop, run directories (and
  loading trained runs), checkpoints, logging, the command line.

`config.py` holds the configuration every layer reads. The modules of the flat layout
before issue 16 (`d2c_jax.trainer`, `d2c_jax.matching`, `d2c_jax.classifier`, ...) stay
importable under their old names, as aliases of the moved modules (`_FLAT_NAMES`), so
users' scripts keep working; `python -m d2c_jax.render`, `d2c_jax.demo` and
`d2c_jax.plots` are the command-line entry points.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import sys

# Old flat module name -> its module in the layered package.
_FLAT_NAMES = {
    "networks": "d2c_jax.core.networks",
    "sac": "d2c_jax.core.sac",
    "replay": "d2c_jax.core.replay",
    "her": "d2c_jax.core.her",
    "rollout": "d2c_jax.core.rollout",
    "classifier": "d2c_jax.curricula.classifier",
    "curriculum": "d2c_jax.curricula.curriculum",
    "matching": "d2c_jax.curricula.matching",
    "trainer": "d2c_jax.training.agent",
    "run_loop": "d2c_jax.training.loop",
    "checkpoint": "d2c_jax.training.checkpoint",
    "logging": "d2c_jax.training.logging",
    "cli": "d2c_jax.training.cli",
    "validation": "d2c_jax.training.validation",
}


class _FlatNameAlias(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Imports `d2c_jax.<old name>` as the very module object it moved to (not a copy),
    lazily: nothing is imported until an old name is."""

    def find_spec(self, fullname, path=None, target=None):
        prefix, _, name = fullname.partition(".")
        if prefix != "d2c_jax" or name not in _FLAT_NAMES:
            return None
        return importlib.util.spec_from_loader(fullname, self)

    def create_module(self, spec):
        return importlib.import_module(_FLAT_NAMES[spec.name.partition(".")[2]])

    def exec_module(self, module):
        """The module already ran under its new name; the import system has just set its
        `__spec__` to the alias's, so give it back its own."""
        module.__spec__ = importlib.util.spec_from_file_location(module.__name__, module.__file__)


if not any(isinstance(finder, _FlatNameAlias) for finder in sys.meta_path):
    sys.meta_path.append(_FlatNameAlias())


def __getattr__(name: str):
    """`d2c_jax.trainer` etc. as attributes, for code that imports the package only."""
    if name in _FLAT_NAMES:
        return importlib.import_module(f"d2c_jax.{name}")
    raise AttributeError(f"module 'd2c_jax' has no attribute {name!r}")
