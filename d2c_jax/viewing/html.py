"""Interactive 3-D views of rollouts, as HTML: brax's web viewer (orbit, zoom, play).

A THIN layer over `brax.io.html`, kept apart so that a later viewer (e.g. MuJoCo's own,
in the browser) can replace this one module without touching its callers. Brax marks
its System and pipelines as no longer actively maintained; only its viewer is used
here: `brax.io.mjcf.load_model` describes the env's geometry, `brax.io.html.render`
writes the page. Callers use only `rollout_html(env, rollout) -> str`, `iframe` and
`save_html(text, path)`; nothing brax leaves this module.

Poses come from host-side forward kinematics of each state's qpos (and mocap_pos), as
the GIF frames do (`render.posed_data`), not from the states' `mjx.Data`: the mazes
never compute body poses, and the physics envs' are one substep old after a step and
stale after a reset.

The page fetches the viewer's JavaScript (three.js, brax's viewer.js) from public CDNs,
so viewing it needs a network connection. It shows the model's geoms only: no goal
markers (the GIFs of `d2c_jax.viewing.render` draw those).
"""

from __future__ import annotations

import copy
import html as html_lib
import pathlib
import warnings

import numpy as np

from d2c_jax.viewing import render

DEFAULT_HEIGHT = 480
"""Height in pixels of one viewer in a page of several (and inline in a notebook)."""


def _brax_system(env, fps: float):
    """brax's System of env.mj_model, whose timestep is one frame (1 / fps seconds): the
    viewer plays one state per timestep."""
    from brax.io import mjcf

    with warnings.catch_warnings():
        # The "not actively maintained" notice: known, and why this layer is thin.
        warnings.simplefilter("ignore", UserWarning)
        # A copy: load_model writes into the model's joint ranges.
        system = mjcf.load_model(copy.copy(env.mj_model))
    return system.replace(opt=system.opt.replace(timestep=1.0 / fps))


def body_poses(env, rollout) -> tuple[np.ndarray, np.ndarray]:
    """World poses of the model's bodies (without the world body) in every state.

    Args:
      env: the GoalEnv the states come from.
      rollout: anything `render.to_trajectory` takes, with any leading axes (...).
    Returns:
      pos (..., nbody - 1, 3) and quaternions rot (..., nbody - 1, 4), float64: MuJoCo's
      xpos and xquat.
    """
    traj = render.to_trajectory(rollout)
    lead = traj.qpos.shape[:-1]
    qpos = traj.qpos.reshape(-1, traj.qpos.shape[-1])
    mocap = traj.mocap_pos.reshape(qpos.shape[0], -1, 3)
    poses = [
        (data.xpos[1:].copy(), data.xquat[1:].copy())
        for data in render.posed_data(env.mj_model, qpos, mocap)
    ]
    nb = env.mj_model.nbody - 1
    pos = np.asarray([p for p, _ in poses]).reshape(*lead, nb, 3)
    rot = np.asarray([r for _, r in poses]).reshape(*lead, nb, 4)
    return pos, rot


def _episode_page(system, pos: np.ndarray, rot: np.ndarray) -> str:
    """brax's full-window viewer page of one episode: pos (T, nb, 3), rot (T, nb, 4)."""
    from brax import base
    from brax.io import html as brax_html

    # The viewer reads only the states' x (the bodies' poses).
    states = [
        base.State(q=None, qd=None, x=base.Transform(pos=p, rot=r), xd=None, contact=None)
        for p, r in zip(pos, rot, strict=True)
    ]
    return brax_html.render(system, states, height=None, colab=False)


def iframe(page: str, height: int = DEFAULT_HEIGHT) -> str:
    """`page` (a whole HTML document) embedded as an <iframe>: each viewer gets its own
    document (brax's page declares an import map, one per document), and notebooks
    show it inline (`IPython.display.HTML(iframe(page))`)."""
    return (
        f'<iframe srcdoc="{html_lib.escape(page, quote=True)}" '
        f'style="width: 100%; height: {int(height)}px; border: 0;"></iframe>'
    )


def rollout_html(
    env, rollout, *, titles=None, height: int = DEFAULT_HEIGHT, fps: float = 20.0
) -> str:
    """An HTML document showing a rollout in brax's interactive 3-D viewer.

    Args:
      env: the GoalEnv the states come from (its `mj_model` is shown).
      rollout: anything `render.to_trajectory` takes (a `rollout.Trace`, EnvState,
        mjx.Data, qpos array): (T, ...) for one episode, a full-window viewer; or
        (n, T, ...) for n episodes, a page of n viewers, one under the other.
      titles: n headings for the episodes of a batch (default "episode i").
      height: pixels per viewer in a page of several.
      fps: states shown per second.
    Returns:
      The HTML text (save it with `save_html`).
    """
    pos, rot = body_poses(env, rollout)
    if pos.ndim == 2:  # one state: an episode of one frame
        pos, rot = pos[None], rot[None]
    system = _brax_system(env, fps)
    if pos.ndim == 3:
        return _episode_page(system, pos, rot)
    pos = pos.reshape(-1, *pos.shape[-3:])
    rot = rot.reshape(-1, *rot.shape[-3:])
    titles = [f"episode {i}" for i in range(len(pos))] if titles is None else list(titles)
    if len(titles) != len(pos):
        raise ValueError(f"{len(titles)} titles for {len(pos)} episodes")
    sections = [
        f"<h3>{html_lib.escape(title)}</h3>\n{iframe(_episode_page(system, p, r), height)}"
        for title, p, r in zip(titles, pos, rot, strict=True)
    ]
    body = "\n".join(sections)
    return (
        '<!DOCTYPE html>\n<html>\n<head><meta charset="utf-8"><title>Rollouts</title></head>\n'
        f'<body style="font-family: sans-serif;">\n{body}\n</body>\n</html>\n'
    )


def save_html(text: str, path) -> pathlib.Path:
    """Writes HTML text (from `rollout_html`) to `path` (parent folders made); returns it."""
    path = pathlib.Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text, encoding="utf-8")
    return path
