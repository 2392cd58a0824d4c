"""`python -m d2c_jax.demo --out runs/demo`: random-policy rollouts drawn over each maze
(`d2c_jax.viewing.demo`, kept at this path for the command and old imports)."""

import sys

from d2c_jax.viewing.demo import *  # noqa: F403  (the pre-issue-16 import path)
from d2c_jax.viewing.demo import main

if __name__ == "__main__":
    sys.exit(main())
