"""Headless rendering: frames of the right shape that show the scene, goal markers, videos.

The drawing tests need an OpenGL backend: OSMesa on CPU (`apt-get install libosmesa6`,
which .ci/run installs) or EGL. They take the `gl_backend` fixture (tests/conftest.py),
which skips them, naming the backend and what is wrong, when none can render; importing
`d2c_jax.viewing.render` needs no GL, so collection never fails for lack of one.
"""

import os
import subprocess
import sys

import imageio.v3 as iio
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs
from d2c_jax.core import rollout
from d2c_jax.viewing import render

SIZE = dict(width=96, height=72)


def _without_gl_vars() -> dict:
    """This environment without the GL choices (PyOpenGL's follows MuJoCo's)."""
    return {k: v for k, v in os.environ.items() if k not in ("MUJOCO_GL", "PYOPENGL_PLATFORM")}


def _run_python(code: str, env: dict | None = None) -> subprocess.CompletedProcess:
    """Runs `code` in a fresh interpreter (default: without the GL variables)."""
    return subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        env=_without_gl_vars() if env is None else env,
        timeout=300,
    )


def go_nowhere(obs, goal, key):
    """No move, no turn."""
    return jnp.zeros(2)


def maze_qpos(*xy_theta) -> np.ndarray:
    """(T, 3) maze qpos from (x, y, theta) triples."""
    return np.array(xy_theta, np.float32)


def test_frames_have_shape_and_dtype_and_show_the_maze(medium_maze, gl_backend):
    frames = render.render_frames(medium_maze, maze_qpos((0, 0, 0), (0, 0, 0)), **SIZE)
    assert frames.shape == (2, 72, 96, 3)
    assert frames.dtype == np.uint8
    assert (frames.reshape(2, -1).std(axis=1) > 10.0).all()  # walls, floor, agent: not blank
    np.testing.assert_array_equal(frames[0], frames[1])  # same state, same picture


def test_frames_differ_when_the_agent_moves(medium_maze, gl_backend):
    still, moved = render.render_frames(medium_maze, maze_qpos((0, 0, 0), (16, 0, 0)), **SIZE)
    changed = np.any(still != moved, axis=-1)
    # The agent left the centre and appeared on the right: both places changed, little else.
    h, w = changed.shape
    assert changed[h // 2 - 3 : h // 2 + 4, w // 2 - 3 : w // 2 + 4].any()
    assert changed[:, w // 2 + 10 :].any()
    assert changed.mean() < 0.05


def test_env_state_batches_keep_their_leading_axes(medium_maze, gl_backend):
    """EnvState (T, B): frames (T, B, height, width, 3); the goal marker is drawn."""
    reset = jax.vmap(medium_maze.reset)(jax.random.split(jax.random.key(0), 2))
    states = jax.tree.map(lambda x: jnp.stack([x, x, x]), reset)  # (T=3, B=2)
    frames = render.render_frames(medium_maze, states, **SIZE)
    assert frames.shape == (3, 2, 72, 96, 3)
    bare = render.render_frames(medium_maze, states, show_goal=False, show_modes=False, **SIZE)
    assert np.any(frames != bare)


@pytest.mark.parametrize("name", ["ant", "sawyer_push"])
def test_physics_envs_render(name, gl_backend):
    """The ant arena from above; the Sawyer table with its mocap gripper and xyz goals."""
    env = envs.make(name)
    state = env.reset_with_goal(jax.random.key(0), env.goal_points[0])
    frame = render.render_frames(env, state, **SIZE)
    assert frame.shape == (72, 96, 3) and frame.std() > 10.0
    bare = render.render_frames(env, state, show_goal=False, show_modes=False, **SIZE)
    assert np.any(frame != bare)


def test_episode_loop_tile_and_gif_round_trip(medium_maze, tmp_path, gl_backend):
    """Episodes of the loop (`rollout.trajectories`, 4 steps) -> frames -> tiles -> GIF."""
    policy = rollout.random_policy(medium_maze.action_dim)
    trace = rollout.trajectories(
        medium_maze, policy, medium_maze.goal_points[:3], jax.random.key(1), steps=4
    )
    frames = render.render_frames(medium_maze, trace, **SIZE)
    assert frames.shape == (3, 5, 72, 96, 3)
    video = render.tile(frames, cols=2)
    assert video.shape == (5, 144, 192, 3)
    assert not video[:, 72:, 96:].any()  # the empty fourth tile is black
    path = render.save_video(video, tmp_path / "rollout.gif", fps=10)
    back = iio.imread(path, index=None)
    assert back.shape[0] == 5 and back.shape[1:3] == (144, 192)
    assert np.abs(back[..., :3].astype(int) - video).mean() < 8  # GIF palette quantisation


def test_to_trajectory_takes_a_rollout_trace(medium_maze):
    """A rollout.Trace becomes a numpy Trajectory with the same fields (no GL needed)."""
    goals = medium_maze.goal_points[:3]
    trace = rollout.trajectories(medium_maze, go_nowhere, goals, jax.random.key(1), steps=2)
    traj = render.to_trajectory(trace)
    assert isinstance(traj, render.Trajectory)
    assert traj.qpos.shape == (3, 3, 3) and traj.goal.shape == (3, 3, 2)
    assert traj.mocap_pos.shape == (3, 3, 0, 3) and traj.success.shape == (3, 3)
    for field in render.Trajectory._fields:
        assert isinstance(getattr(traj, field), np.ndarray)
        np.testing.assert_array_equal(getattr(traj, field), getattr(trace, field))
    np.testing.assert_allclose(traj.goal[:, 0], goals)
    np.testing.assert_array_equal(traj.achieved_goal, traj.qpos[..., :2])


def test_backend_chosen_even_when_mujoco_was_imported_first(tmp_path, gl_backend):
    """MUJOCO_GL is read when `mujoco` is imported; render switches the backend afterwards."""
    code = (
        "import os, mujoco, envs\n"  # mujoco's default (glfw: needs a display) is chosen here
        "from d2c_jax import render\n"
        "print(os.environ.get('MUJOCO_GL'))\n"  # importing render chose nothing
        "frame = render.render_frames(envs.make('spiral_maze'), [[0.0, 0.0, 0.0]])\n"
        "print(os.environ['MUJOCO_GL'], frame.shape, frame.std() > 10)\n"
    )
    backend = render.default_gl_backend()
    if gl_backend != backend:
        pytest.skip(f"checks the default backend ({backend}); MUJOCO_GL={gl_backend} is set")
    out = _run_python(code)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["None", backend, "(1,", "240,", "320,", "3)", "True"]


def test_importing_the_package_sets_no_gl_backend():
    """No side effect at import: MUJOCO_GL stays unset, no GL library is loaded."""
    code = (
        "import os, sys\n"
        "import d2c_jax, d2c_jax.viewing.render, d2c_jax.training.agent, envs\n"
        "print(os.environ.get('MUJOCO_GL'))\n"
        "print(sorted(m for m in ('OpenGL', 'mujoco.osmesa', 'mujoco.egl') if m in sys.modules))\n"
    )
    out = _run_python(code)
    assert out.returncode == 0, out.stderr
    assert out.stdout.splitlines() == ["None", "[]"]


def test_backend_is_chosen_when_a_renderer_is_made(gl_backend):
    """make_renderer applies the user's MUJOCO_GL (here: the usable one) at that moment."""
    code = (
        "import os, mujoco\n"
        "from d2c_jax import render\n"
        f"os.environ['MUJOCO_GL'] = {gl_backend!r}\n"  # set after import: still honoured
        "model = mujoco.MjModel.from_xml_string('<mujoco><worldbody/></mujoco>')\n"
        "with render.make_renderer(model, 8, 8) as r:\n"
        "    r.render()\n"
        "from mujoco.rendering.classic import gl_context\n"
        "print(os.environ['MUJOCO_GL'], gl_context._MUJOCO_GL)\n"
    )
    out = _run_python(code)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == [gl_backend, gl_backend]


def test_unusable_backend_gives_a_clear_error():
    """OSMesa that cannot load (here: PyOpenGL forced to another platform) -> RuntimeError
    whose first line names the backend and what to install."""
    code = (
        "import mujoco\n"
        "from d2c_jax import render\n"
        "model = mujoco.MjModel.from_xml_string('<mujoco><worldbody/></mujoco>')\n"
        "try:\n"
        "    render.make_renderer(model, 8, 8)\n"
        "except RuntimeError as err:\n"
        "    print(err)\n"
    )
    env = {**_without_gl_vars(), "MUJOCO_GL": "osmesa", "PYOPENGL_PLATFORM": "egl"}
    out = _run_python(code, env)
    assert out.returncode == 0, out.stderr
    first = out.stdout.splitlines()[0]
    assert "MUJOCO_GL=osmesa" in first and "apt-get install libosmesa6" in first


def test_gl_backend_available_reports_a_broken_backend_without_failing():
    ok, why = render.gl_backend_available("nosuchgl")
    assert not ok
    assert why.splitlines()[0].startswith("cannot create a MuJoCo OpenGL context")
    assert "MUJOCO_GL=nosuchgl" in why and "invalid value" in why
    assert render.gl_backend_available("nosuchgl") == (ok, why)  # cached
    assert os.environ.get("MUJOCO_GL") != "nosuchgl"  # probed in a subprocess


def test_render_cli_without_a_run_exits_2(tmp_path):
    out = subprocess.run(
        [sys.executable, "-m", "d2c_jax.render", str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert out.returncode == 2
    assert out.stderr.startswith("error: ") and "no config.json" in out.stderr


def test_still_strip_puts_episodes_in_rows_and_moments_in_columns(tmp_path):
    """Pure array layout (no GL): frame value = 10 * episode + step."""
    n, t, h, w = 2, 9, 3, 4
    frames = (10 * np.arange(n)[:, None] + np.arange(t)[None]).astype(np.uint8)
    frames = np.broadcast_to(frames[:, :, None, None, None], (n, t, h, w, 3))
    strip = render.still_strip(frames, n_times=3)  # steps 0, 4, 8
    assert strip.shape == (n * h, 3 * w, 3)
    assert strip[0, 0, 0] == 0 and strip[0, w, 0] == 4 and strip[0, 2 * w, 0] == 8
    assert strip[h, 0, 0] == 10 and strip[h, 2 * w, 0] == 18
    path = render.save_image(strip, tmp_path / "strip.png")
    np.testing.assert_array_equal(iio.imread(path)[..., :3], strip)
