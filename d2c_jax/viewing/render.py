"""Headless MuJoCo rendering of env states: RGB frames, goal markers, GIF/MP4 files.

This module only draws: cameras, markers, frames, tiles, still strips, saving pictures
and videos, and the choice of the OpenGL backend. The episodes it draws come from the
episode loop (`d2c_jax.core.rollout.trajectories`); `d2c_jax.training.commands.render_policy`
(`python -m d2c_jax.render RUN_DIR`) renders a trained run's policy.

Rendering is host side: each state's qpos (and mocap_pos, for the Sawyer gripper's mocap
target) is copied into a CPU `mujoco.MjData`, `mj_forward` computes the geometry
(`posed_data`, which the HTML viewer `d2c_jax.viewing.html` shares) and a
`mujoco.Renderer` draws it. The training step never renders.

The OpenGL backend is chosen when a renderer is made (`make_renderer`), by `viewing.gl`,
whose names are importable from here too.
"""

from __future__ import annotations

import copy
import math
import pathlib
from typing import NamedTuple

import mujoco
import numpy as np

import envs
from d2c_jax.viewing.gl import (  # noqa: F401  (also importable from here, as before)
    GL_BACKEND_HINTS,
    GL_BACKEND_VAR,
    default_gl_backend,
    gl_backend_available,
    gl_error_message,
    resolve_gl_backend,
    use_gl_backend,
)

# Marker colours (RGBA): the episode's goal (gold once reached), and the env's goal modes.
GOAL_RGBA = np.array([0.1, 0.8, 0.2, 0.6], np.float32)
REACHED_RGBA = np.array([1.0, 0.8, 0.0, 0.8], np.float32)
AGENT_RGBA = np.array([0.15, 0.35, 1.0, 0.7], np.float32)
"""A disc under the agent for xy goals (the point agent and the ant are small on a map)."""
MODE_RGBA = np.array([0.9, 0.15, 0.15, 0.35], np.float32)
MARKER_Z = 0.02
"""Height of the disc that marks a 2-D (xy) goal: just above the floor."""
MIN_MARKER_FRACTION = 0.025
"""Goal discs are at least this fraction of the map's width (the radius can be tiny)."""
HEADLIGHT_DIFFUSE_WITH_LIGHTS = 0.15
"""Headlight diffuse for models that light themselves (MuJoCo's default is 0.4)."""
LIGHT_SPECULAR_MAX = 0.1
"""Cap on the models' own lights' specular (MuJoCo's default is 0.3)."""


class Trajectory(NamedTuple):
    """What rendering needs from a rollout; any leading axes (e.g. (n, T) or (T,))."""

    qpos: np.ndarray  # (..., nq)
    mocap_pos: np.ndarray  # (..., nmocap, 3)
    goal: np.ndarray | None  # (..., goal_dim), the goal active in each state, or None
    success: np.ndarray | None  # (...,) bool, or None
    achieved_goal: np.ndarray | None = None  # (..., goal_dim) phi(s), or None


def to_trajectory(rollout) -> Trajectory:
    """A Trajectory (numpy) from a Trajectory, a `rollout.Trace` (any NamedTuple with its
    fields), an EnvState, an mjx.Data or a qpos array (..., nq)."""
    if isinstance(rollout, Trajectory):
        return rollout
    if set(Trajectory._fields) <= set(getattr(rollout, "_fields", ())):
        return Trajectory(*(np.asarray(getattr(rollout, f)) for f in Trajectory._fields))
    if isinstance(rollout, envs.EnvState):
        data = rollout.data
        return Trajectory(
            *(np.asarray(x) for x in (data.qpos, data.mocap_pos, rollout.goal, rollout.success)),
            achieved_goal=np.asarray(rollout.achieved_goal),
        )
    if hasattr(rollout, "qpos"):  # an mjx.Data (or anything with qpos)
        qpos = np.asarray(rollout.qpos)
        mocap = getattr(rollout, "mocap_pos", None)
        mocap = np.asarray(mocap) if mocap is not None else np.zeros((*qpos.shape[:-1], 0, 3))
        return Trajectory(qpos, mocap, None, None)
    qpos = np.asarray(rollout)
    return Trajectory(qpos, np.zeros((*qpos.shape[:-1], 0, 3)), None, None)


# --- cameras and markers ----------------------------------------------------------------


def default_camera(env, width: int = 320, height: int = 240) -> mujoco.MjvCamera:
    """A free camera per env: top-down over the whole layout for the mazes and the ant
    arena (x right, y up, as in `plots.draw_map`); an oblique view of the table for Sawyer.
    """
    cam = mujoco.MjvCamera()
    cam.type = mujoco.mjtCamera.mjCAMERA_FREE
    if hasattr(env, "layout"):
        # Interior bounds plus the outer wall ring, seen straight from above.
        low = np.asarray(env.goal_low)[:2] - env.cell_size
        high = np.asarray(env.goal_high)[:2] + env.cell_size
        half_y, half_x = (high[1] - low[1]) / 2, (high[0] - low[0]) / 2
        half_fovy = math.radians(env.mj_model.vis.global_.fovy) / 2
        # Fit both extents (fovy is vertical), 4% margin, plus the wall height (walls at most
        # 2 high), whose tops are nearer the camera than the floor.
        cam.distance = 1.04 * max(half_y, half_x * height / width) / math.tan(half_fovy) + 2.0
        cam.lookat[:] = [(low[0] + high[0]) / 2, (low[1] + high[1]) / 2, 0.0]
        cam.azimuth, cam.elevation = 90.0, -90.0
    else:
        cam.lookat[:] = [0.0, 0.58, 0.0]
        cam.distance, cam.azimuth, cam.elevation = 1.75, 90.0, -50.0
    return cam


def tracking_camera(
    env, body: str, distance: float = 5.0, azimuth: float = 90.0, elevation: float = -60.0
) -> mujoco.MjvCamera:
    """A camera that follows `body` (e.g. the ant's "torso") from `distance`."""
    cam = mujoco.MjvCamera()
    cam.type = mujoco.mjtCamera.mjCAMERA_TRACKING
    cam.trackbodyid = env.mj_model.body(body).id
    cam.distance, cam.azimuth, cam.elevation = distance, azimuth, elevation
    return cam


def marker_radius(env) -> float:
    """Radius of goal markers: the success radius, at least MIN_MARKER_FRACTION of a map."""
    radius = float(env.success_radius)
    if hasattr(env, "layout"):
        span = float(np.max(np.asarray(env.goal_high) - np.asarray(env.goal_low)))
        radius = max(radius, MIN_MARKER_FRACTION * (span + 2 * env.cell_size))
    return radius


def add_marker(scene: mujoco.MjvScene, point, radius: float, rgba) -> None:
    """Appends a goal marker to `scene`: a flat disc for an xy goal, a sphere for an xyz
    goal. point: (2,) or (3,). No-op when the scene is full.
    """
    if scene.ngeom >= scene.maxgeom:
        return
    point = np.asarray(point, np.float64)
    if point.shape[-1] == 2:
        kind, size = mujoco.mjtGeom.mjGEOM_CYLINDER, [radius, radius, 0.01]
        pos = [point[0], point[1], MARKER_Z]
    else:
        kind, size, pos = mujoco.mjtGeom.mjGEOM_SPHERE, [radius] * 3, point[:3]
    mujoco.mjv_initGeom(
        scene.geoms[scene.ngeom],
        kind,
        np.asarray(size, np.float64),
        np.asarray(pos, np.float64),
        np.eye(3).ravel(),
        np.asarray(rgba, np.float32),
    )
    scene.ngeom += 1


# --- frames -----------------------------------------------------------------------------


def posed_data(model: mujoco.MjModel, qpos: np.ndarray, mocap_pos: np.ndarray):
    """Yields one CPU `mujoco.MjData` of `model` per state, posed by `mj_forward`.

    Args:
      model: the model (not modified).
      qpos: (N, nq) joint positions.
      mocap_pos: (N, nmocap, 3) mocap body positions (the Sawyer gripper's target), or
        (N, 0, 3) to leave them at the model's (a rollout given as qpos only).
    Yields:
      N times the same MjData, holding state i's geometry (xpos, xquat, geom_xpos...):
      read it before taking the next.
    """
    data = mujoco.MjData(model)
    for i in range(qpos.shape[0]):
        data.qpos[:] = qpos[i]
        if model.nmocap and mocap_pos.shape[1]:
            data.mocap_pos[:] = mocap_pos[i]
        mujoco.mj_forward(model, data)
        yield data


def _model_for(env, width: int, height: int) -> mujoco.MjModel:
    """A copy of env.mj_model to render with (the env's own model is never modified).

    Its offscreen buffer fits the frame, and models with their own lights get a dimmer
    headlight (the free camera's light), which would otherwise wash out light surfaces.
    """
    model = copy.copy(env.mj_model)
    vis = model.vis
    vis.global_.offwidth = max(width, vis.global_.offwidth)
    vis.global_.offheight = max(height, vis.global_.offheight)
    if model.nlight:
        vis.headlight.diffuse[:] = HEADLIGHT_DIFFUSE_WITH_LIGHTS
        # A light straight above a top-down camera mirrors into it from every flat surface.
        model.light_specular[:] = np.minimum(model.light_specular, LIGHT_SPECULAR_MAX)
    return model


def make_renderer(model: mujoco.MjModel, width: int, height: int) -> mujoco.Renderer:
    """A mujoco.Renderer, with the GL backend chosen now (`use_gl_backend`).

    Every renderer of this module is made here. Raises a RuntimeError whose first line
    says which backend failed and what to install when no GL context can be made.
    """
    backend = resolve_gl_backend()
    try:
        backend = use_gl_backend()
        return mujoco.Renderer(model, height=height, width=width)
    except Exception as err:  # ImportError, FatalError...: all mean "no usable GL context"
        raise RuntimeError(gl_error_message(backend, f"{type(err).__name__}: {err}")) from err


def render_frames(
    env,
    rollout,
    *,
    width: int = 320,
    height: int = 240,
    camera: mujoco.MjvCamera | None = None,
    show_goal: bool = True,
    show_modes: bool = True,
    show_agent: bool = True,
) -> np.ndarray:
    """RGB frames of a rollout.

    Args:
      env: the GoalEnv the states come from (its `mj_model` is drawn).
      rollout: Trajectory, `rollout.Trace`, EnvState, mjx.Data or qpos array with any
        leading axes (...), e.g. (T,) for one episode or (n, T) for a batch.
      width, height: frame size in pixels.
      camera: a mujoco.MjvCamera; default `default_camera(env, width, height)`.
      show_goal: mark each state's goal when the rollout carries goals (green; gold in
        states that reach it).
      show_modes: mark the env's goal modes (red).
      show_agent: for xy goals, a blue disc under the achieved goal phi(s) (when the
        rollout carries it), so the agent stays visible in small frames.
    Returns:
      (..., height, width, 3) uint8 frames.
    """
    traj = to_trajectory(rollout)
    lead = traj.qpos.shape[:-1]
    qpos = traj.qpos.reshape(-1, traj.qpos.shape[-1])
    mocap = traj.mocap_pos.reshape(qpos.shape[0], -1, 3)
    goals = None
    if show_goal and traj.goal is not None:
        goals = np.asarray(traj.goal).reshape(qpos.shape[0], -1)
        reached = np.zeros(qpos.shape[0], bool)
        if traj.success is not None:
            reached = np.asarray(traj.success).reshape(-1)
    agent = None
    if show_agent and traj.achieved_goal is not None and traj.achieved_goal.shape[-1] == 2:
        agent = np.asarray(traj.achieved_goal).reshape(qpos.shape[0], 2)
    camera = camera if camera is not None else default_camera(env, width, height)
    model = _model_for(env, width, height)
    radius = marker_radius(env)
    frames = np.empty((qpos.shape[0], height, width, 3), np.uint8)
    with make_renderer(model, width, height) as renderer:
        for i, data in enumerate(posed_data(model, qpos, mocap)):
            renderer.update_scene(data, camera)
            if show_modes:
                for point in np.asarray(env.goal_points):
                    add_marker(renderer.scene, point, radius, MODE_RGBA)
            if goals is not None:
                rgba = REACHED_RGBA if reached[i] else GOAL_RGBA
                add_marker(renderer.scene, goals[i], radius, rgba)
            if agent is not None:
                add_marker(renderer.scene, agent[i], 0.6 * radius, AGENT_RGBA)
            renderer.render(out=frames[i])
    return frames.reshape(*lead, height, width, 3)


def tile(frames: np.ndarray, cols: int | None = None) -> np.ndarray:
    """Tiles a batch of videos into one: (n, T, H, W, 3) -> (T, rows * H, cols * W, 3).

    Empty tiles (when n < rows * cols) are black; cols defaults to ceil(sqrt(n)).
    """
    n, t, h, w, c = frames.shape
    cols = cols or math.ceil(math.sqrt(n))
    rows = math.ceil(n / cols)
    grid = np.zeros((rows * cols, t, h, w, c), frames.dtype)
    grid[:n] = frames
    grid = grid.reshape(rows, cols, t, h, w, c).transpose(2, 0, 3, 1, 4, 5)
    return grid.reshape(t, rows * h, cols * w, c)


def still_strip(frames: np.ndarray, n_times: int = 5) -> np.ndarray:
    """One picture of whole episodes: (n, T, H, W, 3) -> (n * H, n_times * W, 3).

    Row i is episode i at `n_times` evenly spaced steps from the first to the last frame.
    """
    n, t, h, w, c = frames.shape
    times = np.linspace(0, t - 1, n_times).round().astype(int)
    picked = frames[:, times]  # (n, n_times, H, W, 3)
    return picked.transpose(0, 2, 1, 3, 4).reshape(n * h, n_times * w, c)


def _imageio():
    """imageio.v3, or an ImportError saying how to install it."""
    try:
        import imageio.v3 as iio
    except ImportError as err:
        raise ImportError(
            "saving videos and pictures needs imageio: "
            "pip install 'd2c_jax[notebooks]' (or imageio)"
        ) from err
    return iio


def save_video(frames: np.ndarray, path, fps: float = 20.0) -> pathlib.Path:
    """Writes frames (T, H, W, 3) uint8 as a GIF (looping) or, for a .mp4 path, an MP4.

    GIF needs only imageio (with Pillow); MP4 also needs an ffmpeg plugin
    (`pip install imageio[ffmpeg]`). Returns the path.
    """
    iio = _imageio()
    path = pathlib.Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    frames = np.asarray(frames, np.uint8)
    if path.suffix.lower() == ".gif":
        iio.imwrite(path, frames, extension=".gif", duration=1000.0 / fps, loop=0)
    else:
        iio.imwrite(path, frames, fps=fps)
    return path


def save_image(image: np.ndarray, path) -> pathlib.Path:
    """Writes one picture (H, W, 3) uint8 (format from the suffix, e.g. .png)."""
    iio = _imageio()
    path = pathlib.Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    iio.imwrite(path, np.asarray(image, np.uint8))
    return path
