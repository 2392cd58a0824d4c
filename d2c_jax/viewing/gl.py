"""The OpenGL backend MuJoCo renders with (MUJOCO_GL): chosen, checked and explained.

Importing this module has no side effect on it. The backend is chosen when a renderer is
made (`render.make_renderer`, through which every `mujoco.Renderer` of the package is
created): `use_gl_backend` sets MUJOCO_GL (the user's value wins; else `egl` with a GPU,
`osmesa` without) and, because MuJoCo reads the variable when `mujoco` is first imported
(its `__init__` imports the classic renderer, whose `gl_context` module reads it) and
`envs` imports `mujoco`, re-executes `gl_context` when it was loaded with another value.
OSMesa needs the system library (Debian: `apt-get install libosmesa6`); EGL needs a GPU
driver (or Mesa's EGL). `gl_backend_available` checks a backend in a subprocess, so that
a failing GL library cannot break the calling process (tests skip with its reason).
"""

from __future__ import annotations

import functools
import importlib
import os
import pathlib
import subprocess
import sys

GL_BACKEND_VAR = "MUJOCO_GL"

# What each backend needs, for the error a user sees when it cannot be loaded.
GL_BACKEND_HINTS = {
    "osmesa": "OSMesa is missing or unusable: install it (Debian/Ubuntu: apt-get install "
    "libosmesa6), or set MUJOCO_GL=egl (a GPU driver or Mesa's libEGL)",
    "egl": "EGL is missing or unusable: it needs a GPU driver or Mesa's libEGL; "
    "or set MUJOCO_GL=osmesa (CPU)",
}


def default_gl_backend() -> str:
    """'egl' when an NVIDIA GPU device node exists, else 'osmesa' (software)."""
    return "egl" if any(pathlib.Path("/dev").glob("nvidia[0-9]*")) else "osmesa"


def resolve_gl_backend(backend: str | None = None) -> str:
    """The backend `use_gl_backend(backend)` would choose; changes nothing."""
    return (backend or os.environ.get(GL_BACKEND_VAR) or default_gl_backend()).lower()


def use_gl_backend(backend: str | None = None) -> str:
    """Makes MuJoCo render with `backend` (default: MUJOCO_GL if set, else the default).

    Sets MUJOCO_GL and, if `mujoco` was already imported with another value, reloads
    mujoco's `gl_context` so that renderers created from now on use the new backend.
    Returns the backend in use. Called by `make_renderer`, never at import.
    """
    chosen = resolve_gl_backend(backend)
    os.environ[GL_BACKEND_VAR] = chosen
    if "mujoco" in sys.modules:
        from mujoco.rendering.classic import gl_context

        if getattr(gl_context, "_MUJOCO_GL", chosen) != chosen:
            try:
                importlib.reload(gl_context)  # the renderer reads gl_context.GLContext per call
            except Exception:
                gl_context._MUJOCO_GL = None  # half reloaded: reload again on the next call
                raise
    return chosen


def gl_error_message(backend: str, err: object) -> str:
    """What is wrong (first line: the backend and what to install), then the cause."""
    hint = GL_BACKEND_HINTS.get(backend, "set MUJOCO_GL=osmesa (CPU) or MUJOCO_GL=egl (GPU)")
    return f"cannot create a MuJoCo OpenGL context with {GL_BACKEND_VAR}={backend}: {hint}\n{err}"


# Run in a fresh interpreter by gl_backend_available: one tiny offscreen frame.
_GL_PROBE = """\
import mujoco
model = mujoco.MjModel.from_xml_string("<mujoco><worldbody/></mujoco>")
with mujoco.Renderer(model, height=8, width=8) as renderer:
    renderer.render()
"""


@functools.lru_cache(maxsize=None)
def _probe_gl_backend(backend: str) -> tuple[bool, str]:
    env = {**os.environ, GL_BACKEND_VAR: backend}
    try:
        out = subprocess.run(
            [sys.executable, "-c", _GL_PROBE],
            capture_output=True,
            text=True,
            env=env,
            timeout=120,
        )
    except subprocess.TimeoutExpired:
        return False, gl_error_message(backend, "the probe timed out after 120 s")
    if out.returncode == 0:
        return True, f"{GL_BACKEND_VAR}={backend} renders"
    lines = out.stderr.strip().splitlines() or [f"the probe exited with {out.returncode}"]
    return False, gl_error_message(backend, lines[-1])  # the exception, at the end


def gl_backend_available(backend: str | None = None) -> tuple[bool, str]:
    """(True, ...) when MuJoCo can render offscreen with `backend` (default: the one
    `make_renderer` would pick), else (False, what is wrong).

    Renders one tiny frame in a subprocess, so a GL library that fails to load (or
    crashes) cannot break this process; cached per backend. Sets nothing here.
    """
    return _probe_gl_backend(resolve_gl_backend(backend))
