"""`python -m d2c_jax.evaluate RUN_DIR [--episodes N] [--checkpoint ITERATION]`: evaluates
a trained run's checkpoint as training does, prints success per mode and writes
RUN_DIR/evaluation-<iteration>.json (`d2c_jax.training.evaluation`)."""

import sys

from d2c_jax.training.evaluation import evaluate_run, main  # noqa: F401

if __name__ == "__main__":
    sys.exit(main())
