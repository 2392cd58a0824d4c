"""Train D2C: `python train.py --env medium_maze --preset quick` (see d2c_jax/cli.py)."""

import sys

from d2c_jax.training import cli

if __name__ == "__main__":
    sys.exit(cli.main())
