"""`python -m d2c_jax.plots RUN_DIR`: (re)draws a run's plots into RUN_DIR/plots;
`python -m d2c_jax.plots compare RUN_DIR... [--metric KEY]`: several runs' success (or
another metric) on one figure (`d2c_jax.viewing.plots`, kept at this path for the command
and old imports)."""

import sys

from d2c_jax.training.commands import plots_main as main
from d2c_jax.viewing.plots import *  # noqa: F403  (the pre-issue-16 import path)

if __name__ == "__main__":
    sys.exit(main())
