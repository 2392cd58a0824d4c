"""The interactive HTML viewer (`d2c_jax.viewing.html`, brax's web viewer).

The page embeds brax's system JSON (base64 of zlib); decoded, it must hold one frame per
state, and each frame the bodies' poses that MJX's own kinematics computes from that
state. No OpenGL is needed, except for the render command (it also draws the GIF).
"""

import base64
import html
import json
import re
import zlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from mujoco import mjx

import envs
from d2c_jax.core import rollout
from d2c_jax.training import agent as agent_lib
from d2c_jax.training import cli, commands, runs
from d2c_jax.viewing import html as viewer_html


def decode_system(page: str) -> dict:
    """The system JSON of one brax viewer page (its script's base64 of zlib)."""
    (encoded,) = re.findall(r'var system = "([A-Za-z0-9+/=]+)";', page)
    return json.loads(zlib.decompress(base64.b64decode(encoded)))


def embedded_pages(document: str) -> list[str]:
    """The viewer pages in the iframes of a page of several episodes."""
    return [html.unescape(s) for s in re.findall(r'<iframe srcdoc="([^"]*)"', document)]


def frame_poses(system: dict) -> tuple[np.ndarray, np.ndarray]:
    """(T, nbody - 1, 3) positions and (T, nbody - 1, 4) quaternions of the viewer's frames."""
    frames = system["states"]["x"]
    return np.array([f["pos"] for f in frames]), np.array([f["rot"] for f in frames])


@jax.jit
def _kinematics(model, data):
    return jax.vmap(mjx.kinematics, in_axes=(None, 0))(model, data)


def mjx_poses(env, data) -> tuple[np.ndarray, np.ndarray]:
    """MJX's xpos[1:] and xquat[1:] of a batch of mjx.Data (T, ...)."""
    posed = _kinematics(env.mjx_model, data)
    return np.asarray(posed.xpos[:, 1:]), np.asarray(posed.xquat[:, 1:])


def datas_at(state: envs.EnvState, qpos, mocap_pos) -> mjx.Data:
    """A batch (T, ...) of the state's mjx.Data with these qpos (T, nq), mocap_pos (T, m, 3)."""
    t = qpos.shape[0]
    batch = jax.tree.map(lambda x: jnp.broadcast_to(x, (t, *x.shape)), state.data)
    return batch.replace(qpos=jnp.asarray(qpos), mocap_pos=jnp.asarray(mocap_pos))


def test_maze_episodes_one_viewer_each_with_a_frame_per_state(medium_maze):
    """Two random 3-step maze episodes: a page of two viewers, 4 frames each; every body
    pose is MJX's kinematics of that state, and the agent body is at phi(s)."""
    env = medium_maze
    policy = rollout.random_policy(env.action_dim)
    trace = rollout.trajectories(env, policy, env.goal_points[:2], jax.random.key(3), steps=3)
    document = viewer_html.rollout_html(env, trace, titles=["first <mode>", "second"], fps=10)
    assert "<h3>first &lt;mode&gt;</h3>" in document
    pages = embedded_pages(document)
    assert len(pages) == 2
    state = env.reset(jax.random.key(0))
    for i, page in enumerate(pages):
        system = decode_system(page)
        assert system["opt"]["timestep"] == pytest.approx(0.1)  # one frame per 1 / fps
        pos, rot = frame_poses(system)
        assert pos.shape == (4, 1, 3) and rot.shape == (4, 1, 4)
        want_pos, want_rot = mjx_poses(env, datas_at(state, trace.qpos[i], trace.mocap_pos[i]))
        np.testing.assert_allclose(pos, want_pos, atol=1e-5)
        np.testing.assert_allclose(rot, want_rot, atol=1e-5)
        np.testing.assert_allclose(pos[:, 0, :2], trace.achieved_goal[i], atol=1e-5)
    assert not np.allclose(*(frame_poses(decode_system(p))[0] for p in pages))


def test_one_episode_is_a_whole_viewer_page(medium_maze):
    qpos = np.array([[0.0, 0.0, 0.0], [1.0, 2.0, 0.5]], np.float32)  # (T=2, nq)
    page = viewer_html.rollout_html(medium_maze, qpos)
    assert page.lstrip().startswith("<!DOCTYPE html>") and "<iframe" not in page
    pos, _ = frame_poses(decode_system(page))
    np.testing.assert_allclose(pos[:, 0, :2], qpos[:, :2], atol=1e-6)
    with pytest.raises(ValueError, match="1 titles for 2 episodes"):
        viewer_html.rollout_html(medium_maze, np.stack([qpos, qpos]), titles=["one"])


def non_quaternion_coordinates(model) -> np.ndarray:
    """(nq,) bool: qpos entries that are not parts of a free or ball joint's quaternion."""
    mask = np.ones(model.nq, bool)
    for kind, adr in zip(model.jnt_type, model.jnt_qposadr, strict=True):
        if kind == 0:  # free: position, then the quaternion
            mask[adr + 3 : adr + 7] = False
        elif kind == 1:  # ball: a quaternion
            mask[adr : adr + 4] = False
    return mask


@pytest.mark.parametrize("name", ["ant", "sawyer_push"])
def test_physics_env_bodies_are_where_mjx_puts_them(name):
    """Three states moved away from a reset (joints, and the Sawyer's mocap target): every
    body of every frame where MJX's kinematics puts it."""
    env = envs.make(name)
    state = jax.jit(env.reset)(jax.random.key(0))
    steps = np.arange(3)[:, None]
    moves = 0.1 * steps * non_quaternion_coordinates(env.mj_model)  # (3, nq)
    qpos = np.asarray(state.data.qpos) + moves
    mocap = np.asarray(state.data.mocap_pos) + 0.02 * steps[:, :, None]  # (3, nmocap, 3)
    data = datas_at(state, qpos, mocap)
    pos, rot = frame_poses(decode_system(viewer_html.rollout_html(env, data)))
    assert pos.shape == (3, env.mj_model.nbody - 1, 3)
    want_pos, want_rot = mjx_poses(env, data)
    np.testing.assert_allclose(pos, want_pos, atol=1e-5)
    np.testing.assert_allclose(rot, want_rot, atol=1e-5)
    assert np.abs(pos[2] - pos[0]).max() > 0.05  # the frames differ


@pytest.mark.slow  # compiles the Ant and Sawyer steps (tens of seconds each on 2 cores)
@pytest.mark.parametrize("name", ["ant", "sawyer_push"])
def test_physics_env_rollout_frames_match_mjx(name):
    """A real random 3-step episode: frame t is MJX's kinematics of state t."""
    env = envs.make(name)
    policy = rollout.random_policy(env.action_dim)
    trace = rollout.trajectories(env, policy, env.goal_points[:1], jax.random.key(1), steps=3)
    episode = jax.tree.map(lambda x: x[0], trace)
    pos, rot = frame_poses(decode_system(viewer_html.rollout_html(env, episode)))
    assert pos.shape[0] == 4
    state = jax.jit(env.reset)(jax.random.key(0))
    want_pos, _ = mjx_poses(env, datas_at(state, trace.qpos[0], trace.mocap_pos[0]))
    np.testing.assert_allclose(pos, want_pos, atol=1e-5)


@pytest.fixture(scope="module")
def untrained_run(tmp_path_factory):
    """A run directory as train.py writes it, holding a fresh (untrained) state's
    checkpoint: all that rendering reads, without training."""
    path = tmp_path_factory.mktemp("render") / "run"
    cfg, _, _ = cli.parse_args(["--env", "medium_maze", "--preset", "tiny"])
    runs.prepare_run_dir(path, cfg, resume=False)
    agent = agent_lib.Agent(cfg, envs.make(cfg.env))
    ckpt = runs.open_checkpointer(path)
    try:
        runs.save_state(ckpt, 1, agent.init_runs())
    finally:
        ckpt.close()
    return path


def test_render_command_writes_a_viewer_per_mode(untrained_run, tmp_path, capsys, gl_backend):
    path, gif = tmp_path / "view" / "policy.html", tmp_path / "policy.gif"
    argv = [str(untrained_run), "--html", str(path), "--size", "16", "--out", str(gif)]
    assert commands.render_main([*argv, "--checkpoint", "1"]) == 0
    assert gif.is_file()  # the video as before
    assert f"wrote {path}" in capsys.readouterr().out.splitlines()
    document = path.read_text()
    env = envs.make("medium_maze")
    titles = re.findall(r"<h3>(.*?)</h3>", document)
    assert [t.split(":")[0] for t in titles] == [f"mode {k}" for k in range(env.n_modes)]
    assert titles[0].startswith("mode 0: goal (16.00, 16.00), ")
    for page in embedded_pages(document):
        pos, _ = frame_poses(decode_system(page))
        assert pos.shape == (env.horizon + 1, 1, 3)  # the reset state and H steps
        np.testing.assert_allclose(pos[0, 0, :2], 0.0, atol=0.2)  # starts near the start


def test_render_command_names_the_checkpoints_there_are(untrained_run, capsys):
    """`--checkpoint` picks the iteration; one without a checkpoint is a one-line exit 2."""
    assert commands.render_main([str(untrained_run), "--checkpoint", "7"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and len(err.strip().splitlines()) == 1
    assert "no checkpoint of iteration 7; it has iterations 1" in err
