"""The Ant: model, contract, physics sanity, walls, determinism.

An MJX ant step compiles in ~10 s on this CPU, so the physics tests share ONE jitted
rollout: H steps (lax.scan) of a batch of envs (vmap), each env in a mode: zero action,
uniform random actions, or placed against a wall with a large velocity toward it (with
zero or random actions). A module-scoped fixture runs it once; the tests read its record.
"""

import chex
import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

import envs
from envs import ant, layouts

H = 300
N_ZERO = 4
N_RANDOM = 34  # 34 envs x 300 steps = 10,200 random steps
# Placed against a wall: torso xy, velocity xy (m/s) toward the wall, action amplitude.
# At most 15 m/s, ten times the fastest gait measured (about 1.5 m/s, benchmarks/ant_gait.py):
# MJX's Newton solve with more than one iteration lets a torso thrown at 20-30 m/s through
# the outer wall (C MuJoCo at any iteration count does not), and one iteration, which held
# there, let the feet slip at walking speed (test_physics_keeps_a_fast_gaits_speed).
WALL_CASES = (
    ((0.0, 1.2), (0.0, 10.0), 0.0),  # the internal wall's lower face (y = 2)
    ((0.0, 1.2), (0.0, 15.0), 1.0),
    ((-4.8, 0.0), (-10.0, 0.0), 0.0),  # the outer wall (x = -6)
    ((-4.8, 0.0), (-15.0, 0.0), 1.0),
    ((-4.8, 8.8), (-10.0, 10.0), 1.0),  # into the top-left corner
    ((4.8, -0.5), (15.0, 0.0), 1.0),  # the outer wall (x = 6) beside the corridor
    ((-3.0, -1.2), (0.0, -15.0), 1.0),  # the lower internal wall's upper face (y = -2)
)
TORSO_RADIUS = 0.25


def place(state, xy, vel):
    """The reset state moved to torso xy (2,) with linear velocity xy (2,)."""
    d = state.data
    return state.replace(data=d.replace(qpos=d.qpos.at[:2].set(xy), qvel=d.qvel.at[:2].set(vel)))


def make_rollout(env):
    """jit(vmap over envs, scan over H steps): records obs (H, B, 29) and success (H, B)."""
    step = chex.assert_max_traces(env.step, n=1)
    reset = chex.assert_max_traces(env.reset, n=1)

    @jax.jit
    def rollout(key, xy, vel, placed, amplitude):
        """xy, vel (B, 2), placed (B,) bool, amplitude (B,): actions amplitude * U[-1, 1]^8."""
        n = xy.shape[0]
        k_reset, k_steps = jax.random.split(key)
        state = jax.vmap(reset)(jax.random.split(k_reset, n))
        moved = jax.vmap(place)(state, xy, vel)
        state = jax.tree.map(
            lambda a, b: jnp.where(placed.reshape((n,) + (1,) * (a.ndim - 1)), a, b), moved, state
        )

        def body(state, key):
            action = amplitude[:, None] * jax.random.uniform(key, (n, 8), minval=-1, maxval=1)
            state = jax.vmap(step)(state, action)
            return state, (state.obs, state.success)

        return jax.lax.scan(body, state, jax.random.split(k_steps, H))

    return rollout


def _inputs():
    """(xy, vel, placed, amplitude) for the zero, random and wall envs, in that order."""
    n_free = N_ZERO + N_RANDOM
    xy = np.zeros((n_free, 2)).tolist() + [c[0] for c in WALL_CASES]
    vel = np.zeros((n_free, 2)).tolist() + [c[1] for c in WALL_CASES]
    placed = [False] * n_free + [True] * len(WALL_CASES)
    amplitude = [0.0] * N_ZERO + [1.0] * N_RANDOM + [c[2] for c in WALL_CASES]
    return tuple(jnp.asarray(v, jnp.float32) for v in (xy, vel, placed, amplitude))


@pytest.fixture(scope="module")
def env():
    return envs.make("ant")


@pytest.fixture(scope="module")
def run(env):
    chex.clear_trace_counter()
    rollout = make_rollout(env)
    inputs = _inputs()
    final, (obs, success) = rollout(jax.random.key(0), *inputs)
    zero = slice(0, N_ZERO)
    rand = slice(N_ZERO, N_ZERO + N_RANDOM)
    wall = slice(N_ZERO + N_RANDOM, None)
    return {
        "rollout": rollout,
        "inputs": inputs,
        "final": final,
        "obs": np.asarray(obs),  # (H, B, 29)
        "success": np.asarray(success),  # (H, B)
        "zero": zero,
        "random": rand,
        "wall": wall,
    }


# --- model, attributes and pure maps (no physics compiled) ---------------------------------
def test_registry_and_attributes(env):
    assert "ant" in envs.ENV_NAMES and env.name == "ant"
    assert (env.obs_dim, env.action_dim, env.goal_dim) == (29, 8, 2)
    assert (env.horizon, env.success_radius) == (300, 1.0)
    np.testing.assert_array_equal(env.goal_points, [[4, 8], [-4, -8]])
    np.testing.assert_array_equal(env.goal_low, [-6, -10])
    np.testing.assert_array_equal(env.goal_high, [6, 10])
    np.testing.assert_array_equal(env.goal_noise_mask, [1, 1])
    assert env.layout == layouts.LAYOUTS["ant"] and env.cell_size == 4.0
    np.testing.assert_array_equal(env.start_goal, [0, 0])
    assert isinstance(env.mj_model, mujoco.MjModel)


def test_model_matches_spec(env):
    m = env.mj_model
    assert m.opt.timestep == 0.01 and ant.N_SUBSTEPS == 5
    assert (m.nq, m.nv, m.nu) == (15, 14, 8)
    assert m.jnt_type[0] == mujoco.mjtJoint.mjJNT_FREE and m.jnt_bodyid[0] == m.body("torso").id
    np.testing.assert_allclose(m.body("torso").pos, [0, 0, 0.75])
    assert m.geom("torso").type == mujoco.mjtGeom.mjGEOM_SPHERE
    np.testing.assert_allclose(m.geom("torso").size[0], TORSO_RADIUS)
    np.testing.assert_allclose(m.actuator_gear[:, 0], 30)
    np.testing.assert_allclose(m.actuator_ctrlrange, np.tile([-1, 1], (8, 1)))
    deg = np.rad2deg(m.jnt_range[1:])
    for leg in range(4):
        np.testing.assert_allclose(deg[2 * leg], [-30, 30], atol=1e-9)  # hip
        sign = 1 if leg in (0, 3) else -1  # legs 1 and 4 bend down for positive angles
        np.testing.assert_allclose(np.sort(sign * deg[2 * leg + 1]), [30, 70], atol=1e-9)
    # Every actuated joint is a hinge in the order hip, ankle of legs 1-4.
    names = [m.joint(int(j)).name for j in m.actuator_trnid[:, 0]]
    assert names == [f"{p}_{leg}" for leg in range(1, 5) for p in ("hip", "ankle")]


def _can_touch(m, g1, g2):
    """MuJoCo's contype/conaffinity rule for the pair (g1, g2)."""
    type_1, type_2 = m.geom_contype[g1], m.geom_contype[g2]
    return bool((type_1 & m.geom_conaffinity[g2]) or (type_2 & m.geom_conaffinity[g1]))


def test_contacts_only_body_with_floor_and_walls(env):
    m = env.mj_model
    names = [m.geom(i).name for i in range(m.ngeom)]
    walls = {n for n in names if n.startswith("wall_")}
    assert len(walls) == len(ant.wall_boxes(ant.LAYOUT)) == 6
    pairs = {
        frozenset((names[i], names[j]))
        for i in range(m.ngeom)
        for j in range(i + 1, m.ngeom)
        if _can_touch(m, i, j)
    }
    touching = {"torso"} | {f"shin_{leg}" for leg in range(1, 5)}
    expected = {frozenset((b, s)) for b in touching for s in walls | {"floor"}}
    assert pairs == expected
    assert m.npair == 0 and m.nexclude == 0


def test_wall_boxes_cover_exactly_the_wall_cells():
    wall = np.array([[ch == "#" for ch in row] for row in ant.LAYOUT])
    covered = np.zeros_like(wall)
    for r0, c0, r1, c1 in ant.wall_boxes(ant.LAYOUT):
        assert wall[r0 : r1 + 1, c0 : c1 + 1].all()  # a box covers only wall cells
        covered[r0 : r1 + 1, c0 : c1 + 1] = True
    np.testing.assert_array_equal(covered, wall)
    # World geometry, by hand: the top wall spans the arena, the internal wall y in [2, 6].
    centres, halves = ant.wall_box_geometry(ant.LAYOUT, ant.CELL_SIZE)
    np.testing.assert_allclose([centres[0], halves[0]], [[0, 12], [10, 2]])
    np.testing.assert_allclose([centres[3], halves[3]], [[4, 4], [6, 2]])


def test_reset_start_state_and_noise(env):
    state = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.key(1), 512))
    qpos, qvel = np.asarray(state.data.qpos), np.asarray(state.data.qvel)
    np.testing.assert_allclose(np.linalg.norm(qpos[:, 3:7], axis=1), 1.0, atol=1e-6)
    noise = qpos - env.start_qpos
    free = np.r_[0:3, 7:15]  # every coordinate but the (renormalised) quaternion
    assert np.abs(noise[:, free]).max() <= 0.1 + 1e-6 and noise[:, free].std(0).min() > 0.05
    assert 0.08 < qvel.std() < 0.12 and abs(qvel.mean()) < 0.01
    np.testing.assert_array_equal(state.obs, np.c_[qpos[:, :15], qvel[:, :14]])
    np.testing.assert_array_equal(state.achieved_goal, qpos[:, :2])
    goals = np.asarray(state.goal)
    assert {tuple(g) for g in goals} == {(4.0, 8.0), (-4.0, -8.0)}
    assert not np.asarray(state.success).any()


def test_normalize_obs_and_goal(env):
    lo, hi = env.mj_model.jnt_range[1:].T
    obs = np.zeros((2, 29), np.float32)
    obs[:, 0:2] = [env.goal_low, env.goal_high]
    obs[:, 2] = [0.25, 0.75]
    obs[:, 3] = 1.0
    obs[:, 7:15] = [lo, hi]
    obs[:, 15:29] = [[-1] * 3 + [-2] * 3 + [-4] * 8, [1] * 3 + [2] * 3 + [4] * 8]
    normed = np.asarray(env.normalize_obs(jnp.asarray(obs)))
    expected = np.r_[-np.ones(3), 1, 0, 0, 0, -np.ones(22)]
    np.testing.assert_allclose(normed[0], expected, atol=1e-6)
    expected[[0, 1, 2] + list(range(7, 29))] = 1
    np.testing.assert_allclose(normed[1], expected, atol=1e-6)
    np.testing.assert_allclose(env.normalize_goal(jnp.array([6.0, -10.0])), [1, -1])


# --- physics: one compiled rollout ---------------------------------------------------------
def test_rollout_contract_shapes_and_finite(env, run):
    final, n = run["final"], run["obs"].shape[1]
    chex.assert_shape(final.obs, (n, 29))
    chex.assert_shape([final.achieved_goal, final.goal], (n, 2))
    chex.assert_shape(final.success, (n,))
    chex.assert_shape([final.data.qpos, final.data.qvel], [(n, 15), (n, 14)])
    assert final.obs.dtype == jnp.float32 and final.success.dtype == jnp.bool_
    np.testing.assert_array_equal(final.obs, run["obs"][-1])
    np.testing.assert_array_equal(final.achieved_goal, run["obs"][-1, :, :2])
    # phi read back from the obs (the relative goal input's map) is the achieved goal
    np.testing.assert_array_equal(env.goal_of_obs(final.obs), final.achieved_goal)
    chex.assert_shape(run["obs"], (H, n, 29))
    assert np.isfinite(run["obs"]).all()


def test_same_key_same_trajectory_no_retrace(run):
    """A second call reuses the compiled rollout (assert_max_traces(n=1) on reset and step
    would raise on a retrace) and reproduces the run bit for bit."""
    _, (obs, success) = run["rollout"](jax.random.key(0), *run["inputs"])
    np.testing.assert_array_equal(np.asarray(obs), run["obs"])
    np.testing.assert_array_equal(np.asarray(success), run["success"])


def _up_z(quat):
    """z component of the torso's up axis, from quaternions (..., 4) (w, x, y, z)."""
    _, x, y, _ = np.moveaxis(quat, -1, 0)
    return 1 - 2 * (x**2 + y**2)


def test_zero_action_settles_upright_near_start(run):
    obs = run["obs"][:, run["zero"]]
    z, xy = obs[..., 2], obs[..., :2]
    print(f"zero action: torso z in [{z.min():.3f}, {z.max():.3f}], final {z[-1].round(3)}")
    assert z.min() > 0.3  # above 0.3 for all 300 steps
    assert np.abs(np.diff(z[-50:], axis=0)).max() < 1e-3  # settled: at rest
    assert _up_z(obs[..., 3:7]).min() > 0.95  # upright
    assert np.linalg.norm(xy, axis=-1).max() < 0.5  # near (0, 0)
    assert np.abs(obs[-1, :, 15:]).max() < 0.05  # velocities have died out


def test_random_actions_move_the_torso(env, run):
    obs = run["obs"][:, run["random"]]
    path = np.linalg.norm(np.diff(obs[..., :2], axis=0), axis=-1).sum(0)  # (n,)
    displacement = np.linalg.norm(obs[-1, :, :2] - obs[0, :, :2], axis=-1)
    print(f"random: path length median {np.median(path):.2f}, displacement {displacement}")
    assert np.median(path) > 1.0 and displacement.max() > 0.5
    assert np.isfinite(obs).all()  # 10,200 random steps, no NaN
    assert obs[..., 2].min() > 0.1 and obs[..., 2].max() < 3.0
    # normalize_obs's fixed scales keep random motion's features about [-1, 1].
    normed = np.abs(np.asarray(env.normalize_obs(jnp.asarray(obs))))
    print(f"random: 99th percentile of |normalised obs| {np.percentile(normed, 99, axis=(0, 1))}")
    assert np.percentile(normed, 99, axis=(0, 1)).max() < 2.0


def _signed_distance_to_walls(xy, centres, halves):
    """Signed distance (...,) from points xy (..., 2) to the nearest wall box (< 0 inside)."""
    d = np.abs(xy[..., None, :] - centres) - halves  # (..., n, 2)
    outside = np.linalg.norm(np.maximum(d, 0), axis=-1)
    inside = np.minimum(d.max(-1), 0)
    return (outside + inside).min(-1)


def test_torso_never_crosses_a_wall(env, run):
    """Every env, including the ones thrown at a wall at 10-15 m/s: the torso sphere stays
    outside every wall box (at most 3 cm of penetration)."""
    dist = _signed_distance_to_walls(run["obs"][..., :2], env.wall_centres, env.wall_halves)
    print(f"closest torso centre to a wall per thrown env: {dist[:, run['wall']].min(0).round(3)}")
    assert dist.min() > TORSO_RADIUS - 0.03
    # The thrown envs really reached their wall: from >= 0.8 away to within a leg's reach
    # (a shin often touches first and holds the torso off).
    placed_xy = np.asarray(run["inputs"][0])[run["wall"]]
    start = _signed_distance_to_walls(placed_xy, env.wall_centres, env.wall_halves)
    assert (start >= 0.8 - 1e-6).all() and (dist[:, run["wall"]].min(0) < 0.5).all()


def test_physics_keeps_a_fast_gaits_speed():
    """The env's physics must not slow the ant: the Ant task needs speed (20 units of
    corridor to the nearer mode in H = 300 steps). A fast open-loop gait (found under RK4
    with a converged solve, benchmarks/ant_gait.py) covers as much path under the env's
    settings (RK4, 2 Newton iterations) as under the paper's physics converged (RK4, C
    MuJoCo, the same 16 env resets; 4 were too few: one draw's chaotic heading moved the
    means by 10-20%). The settings the env had before lost path: Euler at the same
    timestep about a fifth even with a converged solve, and one Newton iteration a third;
    the second assertion keeps that sensitivity of the probe in view."""
    from benchmarks import ant_gait

    def mean_path(physics):
        model = ant_gait.open_arena_model(physics)
        return ant_gait.path_lengths(model, ant_gait.FAST_GAIT, draws=16)[:, 0].mean()

    env_path, rk4, euler = (mean_path(p) for p in ("env", "rk4", "euler"))
    print(f"gait path: env {env_path:.2f}, RK4 converged {rk4:.2f}, Euler converged {euler:.2f}")
    assert env_path >= 0.9 * rk4
    assert euler < 0.85 * rk4
