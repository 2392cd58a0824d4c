"""`python -m d2c_jax.render RUN_DIR [--out policy.gif] [--still strip.png]`: renders a
trained run's policy reaching each goal mode (`d2c_jax.training.commands.render_main`).

Kept at this path for the command and for `import d2c_jax.render`; the drawing code is
`d2c_jax.viewing.render`.
"""

import sys

from d2c_jax.training.commands import render_main as main
from d2c_jax.training.commands import render_policy, trained_policy  # noqa: F401
from d2c_jax.training.runs import load_run  # noqa: F401
from d2c_jax.viewing.render import *  # noqa: F403  (the pre-issue-16 import path)

if __name__ == "__main__":
    sys.exit(main())
