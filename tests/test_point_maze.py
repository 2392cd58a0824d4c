"""The three point mazes: contract, solid walls, solvability, success and determinism."""

import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs
from envs import layouts
from envs.point_maze import CLEARANCE, PointMaze, distance_to_walls, wrap_angle

MAZES = ("complex_maze", "medium_maze", "spiral_maze")


@pytest.fixture(scope="module", params=MAZES)
def maze(request):
    return envs.make(request.param)


def test_registry_lists_mazes_and_rejects_unknown():
    assert envs.ENV_NAMES[:3] == MAZES
    with pytest.raises(ValueError, match="valid ids: complex_maze, medium_maze"):
        envs.make("nope")


def test_reset_step_jit_vmap_shapes_and_no_retrace(maze):
    chex.clear_trace_counter()  # the counter is keyed by function name, shared across mazes
    reset = jax.jit(jax.vmap(chex.assert_max_traces(maze.reset, n=1)))
    step = jax.jit(jax.vmap(chex.assert_max_traces(maze.step, n=1)))
    state = reset(jax.random.split(jax.random.key(0), 8))
    for i in range(3):
        actions = jax.random.uniform(jax.random.key(i), (8, 2), minval=-1, maxval=1)
        state = step(state, actions)
    chex.assert_shape(state.obs, (8, maze.obs_dim))
    chex.assert_shape(state.achieved_goal, (8, maze.goal_dim))
    chex.assert_shape(state.goal, (8, maze.goal_dim))
    chex.assert_shape(state.success, (8,))
    chex.assert_shape(state.data.qpos, (8, 3))
    assert np.isfinite(np.asarray(state.obs)).all()
    np.testing.assert_array_equal(maze.goal_of_obs(state.obs), state.achieved_goal)
    # Goals of reset are mode points.
    goals = np.asarray(state.goal)
    assert all(np.abs(maze.goal_points - g).sum(-1).min() == 0 for g in goals)


def test_layout_attributes_match_spec(maze):
    assert maze.cell_size == 4.0
    assert maze.layout == layouts.LAYOUTS[maze.name]
    rows, cols = len(maze.layout), len(maze.layout[0])
    assert (rows, cols) == (11, 9 if maze.name == "spiral_maze" else 11)
    width = 28 if maze.name == "spiral_maze" else 36
    np.testing.assert_allclose(maze.goal_high - maze.goal_low, [width, 36])


def test_move_stops_exactly_at_clearance(medium_maze):
    """Hand-computed: the start row's right end wall is the box x in [18, 22]."""
    state = medium_maze.reset_with_goal(jax.random.key(0), jnp.zeros(2))
    data = state.data.replace(qpos=jnp.array([17.0, 0.0, 0.0]))
    state = medium_maze.step(state.replace(data=data), jnp.array([1.0, 0.0]))
    np.testing.assert_allclose(state.achieved_goal, [18.0 - CLEARANCE, 0.0], atol=1e-5)
    # A diagonal move at the convex corner (2, 2) of the wall block of cells x,y in [2, 6]
    # (medium maze, row 4 col 6) stops on the rounded corner: distance exactly 0.4.
    data = state.data.replace(qpos=jnp.array([1.2, 1.2, jnp.pi / 4]))
    state = medium_maze.step(state.replace(data=data), jnp.array([1.0, 0.0]))
    expected = 2.0 - CLEARANCE / np.sqrt(2.0)
    np.testing.assert_allclose(state.achieved_goal, [expected, expected], atol=1e-5)


def _toward_nearest_wall(env, xy):
    """Unit vector (2,) from xy toward the nearest point of the nearest wall box."""
    centers = jnp.asarray(env.wall_centers)
    nearest = jnp.clip(xy, centers - env.wall_half, centers + env.wall_half)  # (n, 2)
    dist = jnp.linalg.norm(nearest - xy, axis=-1)
    delta = nearest[jnp.argmin(dist)] - xy
    return delta / (jnp.linalg.norm(delta) + 1e-9)


def _stress(env, policy, n_envs, n_steps, key):
    """Min wall distance and the xy box visited over n_envs x n_steps steps of `policy`."""

    def one_env(key):
        key_reset, key_run = jax.random.split(key)
        state = env.reset(key_reset)

        def body(state, key):
            state = env.step(state, policy(state, key))
            xy = state.achieved_goal
            d = distance_to_walls(xy, jnp.asarray(env.wall_centers), env.wall_half)
            return state, (d, xy)

        _, (d, xy) = jax.lax.scan(body, state, jax.random.split(key_run, n_steps))
        return d.min(), xy.min(0), xy.max(0)

    return jax.jit(jax.vmap(one_env))(jax.random.split(key, n_envs))


@pytest.mark.parametrize("policy_name", ["random", "adversarial"])
def test_walls_are_solid_over_100k_steps(maze, policy_name):
    def random_policy(state, key):
        return jax.random.uniform(key, (2,), minval=-1, maxval=1)

    def adversarial_policy(state, key):
        # Full speed into the nearest wall, with a random heading error so it also
        # grazes corners and slides along faces.
        to_wall = _toward_nearest_wall(maze, state.achieved_goal)
        angle = jnp.arctan2(to_wall[1], to_wall[0]) + jax.random.uniform(
            key, (), minval=-1.2, maxval=1.2
        )
        turn = jnp.clip(wrap_angle(angle - state.obs[2]), -1.0, 1.0)
        return jnp.stack([1.0, turn])

    policy = random_policy if policy_name == "random" else adversarial_policy
    d_min, lo, hi = _stress(maze, policy, n_envs=100, n_steps=1000, key=jax.random.key(1))
    assert float(d_min.min()) >= CLEARANCE - 1e-3
    assert (np.asarray(lo) >= maze.goal_low + CLEARANCE - 1e-3).all()
    assert (np.asarray(hi) <= maze.goal_high - CLEARANCE + 1e-3).all()


def test_goal_points_are_free_cells(maze):
    for g in maze.goal_points:
        cell = layouts.point_to_cell(maze.layout, g, maze.cell_size)
        assert layouts.is_free(maze.layout, cell)
        np.testing.assert_allclose(layouts.cell_center(maze.layout, cell, maze.cell_size), g)


def bfs_waypoints(env, goal):
    """Cell-centre waypoints (n, 2) of the BFS path from the start cell to `goal`."""
    start = layouts.start_cell(env.layout)
    target = layouts.point_to_cell(env.layout, goal, env.cell_size)
    path = layouts.shortest_path(env.layout, start, target)
    return np.stack([layouts.cell_center(env.layout, c, env.cell_size) for c in path])


def scripted_episode(env, waypoints, key):
    """Follows the waypoints (pure pursuit, next waypoint once within 1.5); success flags (H,)."""
    waypoints = jnp.asarray(waypoints)
    state = env.reset_with_goal(key, waypoints[-1])

    def body(carry, _):
        state, i = carry
        xy = state.achieved_goal
        near = jnp.linalg.norm(waypoints[i] - xy) < 1.5
        i = jnp.minimum(i + near.astype(jnp.int32), waypoints.shape[0] - 1)
        delta = waypoints[i] - xy
        turn = jnp.clip(wrap_angle(jnp.arctan2(delta[1], delta[0]) - state.obs[2]), -1.0, 1.0)
        move = jnp.minimum(jnp.linalg.norm(delta), 1.0)
        state = env.step(state, jnp.stack([move, turn]))
        return (state, i), state.success

    _, success = jax.lax.scan(body, (state, 1), None, length=env.horizon)
    return success


def test_bfs_controller_reaches_every_goal_within_horizon(maze):
    expected_cells = {"complex_maze": 10, "medium_maze": 8, "spiral_maze": 17}[maze.name]
    run = jax.jit(lambda wp, key: scripted_episode(maze, wp, key))
    longest = 0
    for g in maze.goal_points:
        waypoints = bfs_waypoints(maze, g)
        longest = max(longest, len(waypoints) - 1)
        success = np.asarray(run(waypoints, jax.random.key(3)))
        assert success.any(), f"goal {g} not reached in {maze.name}"
    assert longest == expected_cells


def test_success_exactly_within_radius_and_after_set_goal(medium_maze):
    env = medium_maze
    state = env.reset_with_goal(jax.random.key(0), jnp.array([16.0, 16.0]))
    ag = state.achieved_goal
    inside = ag + jnp.array([env.success_radius - 1e-4, 0.0])
    outside = ag + jnp.array([env.success_radius + 1e-4, 0.0])
    assert bool(env.set_goal(state, inside).success)
    assert not bool(env.set_goal(state, outside).success)
    assert not bool(state.success)
    # After a step the flag follows the goal set last.
    state = env.set_goal(state, inside)
    stepped = env.step(state, jnp.zeros(2))
    assert bool(stepped.success)


def test_same_key_same_trajectory(medium_maze):
    env = medium_maze

    @jax.jit
    def rollout(key):
        key_reset, key_act = jax.random.split(key)
        state = env.reset(key_reset)

        def body(state, k):
            state = env.step(state, jax.random.uniform(k, (2,), minval=-1, maxval=1))
            return state, state.obs

        return jax.lax.scan(body, state, jax.random.split(key_act, 50))[1]

    a, b, c = rollout(jax.random.key(7)), rollout(jax.random.key(7)), rollout(jax.random.key(8))
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


def test_normalization_maps_reachable_range_to_unit_box(maze):
    d_lo, d_hi = maze.goal_low, maze.goal_high
    corners = jnp.array([d_lo, d_hi])
    np.testing.assert_allclose(maze.normalize_goal(corners), [[-1, -1], [1, 1]], atol=1e-6)
    obs = jnp.array(
        [[d_lo[0], d_lo[1], -np.pi, -50, -50, -50], [d_hi[0], d_hi[1], 3.0, 50, 50, 50]]
    )
    feats = np.asarray(maze.normalize_obs(obs))
    assert feats.shape == (2, 7)
    assert np.abs(feats).max() <= 1.0 + 1e-6
    np.testing.assert_allclose(feats[:, :2], [[-1, -1], [1, 1]], atol=1e-6)


def test_custom_layout_and_bad_layouts():
    arena = ("#####", "#...#", "#.S.#", "#...#", "#####")
    env = PointMaze(maze="arena", layout=arena, goal_points=[(4.0, 4.0)])
    np.testing.assert_allclose(env.goal_low, [-6, -6])
    with pytest.raises(ValueError, match="exactly one start"):
        PointMaze(maze="x", layout=("###", "#.#", "###"), goal_points=[(0, 0)])
    with pytest.raises(ValueError, match="ring of walls"):
        PointMaze(maze="x", layout=("#.#", "#S#", "###"), goal_points=[(0, 0)])
