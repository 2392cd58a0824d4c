"""Headless rendering: frames of the right shape that show the scene, goal markers, videos.

These tests need an OpenGL backend: OSMesa on CPU (`apt-get install libosmesa6`, which
.ci/run installs) or EGL. Without one they fail with render.make_renderer's message.
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
from d2c_jax import render

SIZE = dict(width=96, height=72)


def maze_qpos(*xy_theta) -> np.ndarray:
    """(T, 3) maze qpos from (x, y, theta) triples."""
    return np.array(xy_theta, np.float32)


def test_frames_have_shape_and_dtype_and_show_the_maze(medium_maze):
    frames = render.render_frames(medium_maze, maze_qpos((0, 0, 0), (0, 0, 0)), **SIZE)
    assert frames.shape == (2, 72, 96, 3)
    assert frames.dtype == np.uint8
    assert (frames.reshape(2, -1).std(axis=1) > 10.0).all()  # walls, floor, agent: not blank
    np.testing.assert_array_equal(frames[0], frames[1])  # same state, same picture


def test_frames_differ_when_the_agent_moves(medium_maze):
    still, moved = render.render_frames(medium_maze, maze_qpos((0, 0, 0), (16, 0, 0)), **SIZE)
    changed = np.any(still != moved, axis=-1)
    # The agent left the centre and appeared on the right: both places changed, little else.
    h, w = changed.shape
    assert changed[h // 2 - 3 : h // 2 + 4, w // 2 - 3 : w // 2 + 4].any()
    assert changed[:, w // 2 + 10 :].any()
    assert changed.mean() < 0.05


def test_env_state_batches_keep_their_leading_axes(medium_maze):
    """EnvState (T, B): frames (T, B, height, width, 3); the goal marker is drawn."""
    reset = jax.vmap(medium_maze.reset)(jax.random.split(jax.random.key(0), 2))
    states = jax.tree.map(lambda x: jnp.stack([x, x, x]), reset)  # (T=3, B=2)
    frames = render.render_frames(medium_maze, states, **SIZE)
    assert frames.shape == (3, 2, 72, 96, 3)
    bare = render.render_frames(medium_maze, states, show_goal=False, show_modes=False, **SIZE)
    assert np.any(frames != bare)


@pytest.mark.parametrize("name", ["ant", "sawyer_push"])
def test_physics_envs_render(name):
    """The ant arena from above; the Sawyer table with its mocap gripper and xyz goals."""
    env = envs.make(name)
    state = env.reset_with_goal(jax.random.key(0), env.goal_points[0])
    frame = render.render_frames(env, state, **SIZE)
    assert frame.shape == (72, 96, 3) and frame.std() > 10.0
    bare = render.render_frames(env, state, show_goal=False, show_modes=False, **SIZE)
    assert np.any(frame != bare)


def test_run_episodes_tile_and_gif_round_trip(medium_maze, tmp_path):
    policy = render.random_policy(medium_maze)
    traj = render.run_episodes(
        medium_maze, policy, medium_maze.goal_points[:3], jax.random.key(1), 4
    )
    assert traj.qpos.shape == (3, 5, 3) and traj.goal.shape == (3, 5, 2)
    np.testing.assert_allclose(traj.goal[:, 0], medium_maze.goal_points[:3])
    frames = render.render_frames(medium_maze, traj, **SIZE)
    assert frames.shape == (3, 5, 72, 96, 3)
    video = render.tile(frames, cols=2)
    assert video.shape == (5, 144, 192, 3)
    assert not video[:, 72:, 96:].any()  # the empty fourth tile is black
    path = render.save_video(video, tmp_path / "rollout.gif", fps=10)
    back = iio.imread(path, index=None)
    assert back.shape[0] == 5 and back.shape[1:3] == (144, 192)
    assert np.abs(back[..., :3].astype(int) - video).mean() < 8  # GIF palette quantisation


def test_backend_chosen_even_when_mujoco_was_imported_first(tmp_path):
    """MUJOCO_GL is read when `mujoco` is imported; render switches the backend afterwards."""
    code = (
        "import mujoco, envs\n"  # mujoco's default (glfw: needs a display) is chosen here
        "from d2c_jax import render\n"
        "frame = render.render_frames(envs.make('spiral_maze'), [[0.0, 0.0, 0.0]])\n"
        "print(render.os.environ['MUJOCO_GL'], frame.shape, frame.std() > 10)\n"
    )
    env = {k: v for k, v in os.environ.items() if k != "MUJOCO_GL"}
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300
    )
    assert out.returncode == 0, out.stderr
    backend = render.default_gl_backend()
    assert out.stdout.split() == [backend, "(1,", "240,", "320,", "3)", "True"]


def test_render_cli_without_a_run_exits_2(tmp_path):
    out = subprocess.run(
        [sys.executable, "-m", "d2c_jax.render", str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert out.returncode == 2
    assert out.stderr.startswith("error: ") and "no config.json" in out.stderr
