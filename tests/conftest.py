"""Test setup: CPU only, shared compiled environments."""

import os
import tempfile

os.environ["JAX_PLATFORMS"] = "cpu"
os.environ.setdefault("XLA_FLAGS", "--xla_cpu_multi_thread_eigen=false")
# One persistent compilation cache for every test process (xdist workers and the CLI
# subprocesses): the tiny trainer runs compile the same programs many times.
os.environ.setdefault(
    "JAX_COMPILATION_CACHE_DIR", os.path.join(tempfile.gettempdir(), "d2c_jax_test_xla_cache")
)
os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0.5")

import pytest  # noqa: E402


@pytest.fixture(scope="session")
def medium_maze():
    """The medium maze env, built once per test session."""
    import envs

    return envs.make("medium_maze")


@pytest.fixture
def gl_backend():
    """The MuJoCo GL backend a renderer would use; skips the test, saying why, when it
    cannot render (checked once per process, in a subprocess: see render.gl_backend_available)."""
    from d2c_jax.viewing import render

    backend = render.resolve_gl_backend()
    ok, why = render.gl_backend_available(backend)
    if not ok:
        pytest.skip("no usable OpenGL backend: " + why.replace("\n", " | "))
    return backend


@pytest.fixture(scope="session")
def undocumented_metrics():
    """A function: the keys of metrics rows that docs/METRICS.md does not list (a per-mode
    key `eval/success/3` counts as its pattern `eval/success/<k>`)."""
    import pathlib
    import re

    text = (pathlib.Path(__file__).resolve().parents[1] / "docs" / "METRICS.md").read_text()
    documented = set(re.findall(r"^\| `([^`]+)` \|", text, flags=re.MULTILINE))

    def check(rows: list[dict]) -> set[str]:
        keys = {re.sub(r"/\d+$", "/<k>", k) for row in rows for k in row}
        return keys - documented

    return check
