"""Every environment trains: the tiny preset's train and eval steps on each env id.

A new env, or a trainer change that breaks one env (as `env.start_goal` traced inside the
step once broke Sawyer), fails here rather than in a user's run.
"""

import numpy as np
import pytest

import envs
from d2c_jax import cli, trainer


@pytest.mark.parametrize("env_name", envs.ENV_NAMES)
def test_tiny_preset_trains_and_evaluates(env_name, tmp_path):
    cfg, _, _ = cli.parse_args(["--env", env_name, "--preset", "tiny"])
    out = tmp_path / "run"
    assert trainer.train(cfg, out, quiet=True) == 0
    from d2c_jax import logging as logging_lib

    rows = logging_lib.read_metrics(out / "metrics.jsonl")
    assert [r["iteration"] for r in rows] == [1, 2]
    last = rows[-1]
    env = envs.make(env_name)
    assert all(f"eval/success/{k}" in last for k in range(env.n_modes))
    for key in ("eval/success", "curriculum/distance", "sac/critic_loss", "classifier/loss"):
        assert np.isfinite(last[key]), key
    assert (out / "plots" / "curriculum.png").exists()
