"""Test setup: CPU only, shared compiled environments."""

import os

os.environ["JAX_PLATFORMS"] = "cpu"
os.environ.setdefault("XLA_FLAGS", "--xla_cpu_multi_thread_eigen=false")

import pytest  # noqa: E402


@pytest.fixture(scope="session")
def medium_maze():
    """The medium maze env, built once per test session."""
    import envs

    return envs.make("medium_maze")
