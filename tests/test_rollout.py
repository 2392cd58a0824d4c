"""Episode collection and evaluation on the medium maze with scripted policies."""

import jax
import jax.numpy as jnp
import numpy as np

from d2c_jax.core import rollout


def go_right(obs, goal, key):
    """Full speed along +x (heading starts near 0)."""
    return jnp.array([1.0, -obs[2]])


def test_collect_shapes_and_goal_assignment(medium_maze):
    env = medium_maze
    goals = jnp.array([[100.0, 100.0], [200.0, 200.0], [300.0, 300.0]])  # unreachable
    ep = jax.jit(
        lambda k: rollout.collect(env, rollout.random_policy(2), lambda ag, k: ag, goals, 5, k)
    )(jax.random.key(0))
    h = env.horizon
    assert ep.obs.shape == (5, h + 1, 6) and ep.achieved_goal.shape == (5, h + 1, 2)
    assert ep.action.shape == (5, h, 2) and ep.goal.shape == (5, h, 2)
    # env i is conditioned on curriculum goal i mod K, all along (never reached).
    np.testing.assert_array_equal(ep.goal[:, 0], goals[np.arange(5) % 3])
    np.testing.assert_array_equal(ep.goal, jnp.broadcast_to(ep.goal[:, :1], ep.goal.shape))
    np.testing.assert_array_equal(ep.obs[:, 1:, :2], ep.achieved_goal[:, 1:])
    assert (np.abs(ep.action) <= 1).all()


def test_goal_switches_after_success_and_transitions_keep_active_goal(medium_maze):
    env = medium_maze
    # Going right from the origin reaches (3, 0) after 3 steps; the next goal is 4 units
    # further along, so each success triggers a switch.
    next_goal = lambda ag, key: ag + jnp.array([4.0, 0.0])  # noqa: E731
    ep = rollout.collect(env, go_right, next_goal, jnp.array([[3.0, 0.0]]), 1, jax.random.key(1))
    success = np.asarray(ep.success[0])
    goals = np.asarray(ep.goal[0])
    first = int(np.argmax(success))
    assert success[first] and first <= 4
    np.testing.assert_array_equal(goals[first], [3.0, 0.0])  # active when the step was taken
    ag_at_success = np.asarray(ep.achieved_goal[0, first + 1])
    np.testing.assert_allclose(goals[first + 1], ag_at_success + [4.0, 0.0])
    assert success.sum() >= 2  # it keeps switching and reaching until the wall


def test_evaluate_scores_reachable_and_unreachable_modes(medium_maze):
    env = medium_maze
    # The wall-hugging "go right" policy never reaches any corner mode.
    score = jax.jit(lambda k: rollout.evaluate(env, go_right, 3, k))(jax.random.key(0))
    np.testing.assert_array_equal(score, np.zeros(4))

    def oracle(obs, goal, key):
        """Along the y = 0 corridor to the goal's column, then up/down; no wall contact."""
        xy = obs[:2]
        along = jnp.abs(goal[0] - xy[0]) > 0.3
        # Turn on the spot (move 0) until facing the target, so moves never graze walls.
        target = jnp.where(along, jnp.array([goal[0], 0.0]), goal)
        d = target - xy
        heading = jnp.arctan2(d[1], d[0])
        error = (heading - obs[2] + jnp.pi) % (2 * jnp.pi) - jnp.pi
        turn = jnp.clip(error, -1, 1)
        move = jnp.where(jnp.abs(error) < 0.5, jnp.minimum(jnp.linalg.norm(d), 1.0), 0.0)
        return jnp.array([move, turn])

    score = jax.jit(lambda k: rollout.evaluate(env, oracle, 3, k))(jax.random.key(0))
    np.testing.assert_array_equal(score, np.ones(4))


def test_each_env_draws_its_own_key_stream(medium_maze):
    """Env i's actions come from keys[i] = split(key, n)[i] alone: adding envs or batching
    them differently never changes another env's episode."""
    env = medium_maze
    goals = jnp.array([[100.0, 100.0]])  # unreachable: no goal switch
    key = jax.random.key(3)
    ep = rollout.collect(env, rollout.random_policy(2), lambda ag, k: ag, goals, 3, key)
    env_key = jax.random.split(key, 3)[1]
    step_keys = jax.random.split(jax.random.split(env_key)[1], env.horizon)
    want = [rollout.random_policy(2)(None, None, jax.random.split(k)[0]) for k in step_keys[:5]]
    np.testing.assert_array_equal(ep.action[1, :5], np.stack(want))


def test_random_walk_switches_every_n_steps_and_marks_its_start(medium_maze):
    env = medium_maze
    # The curriculum goal (3, 0) is reached after ~3 steps; post-success goals are
    # unreachable (far above, a fresh one per draw), so only the timer switches them.
    far = lambda ag, key: ag + jnp.array([0.0, 100.0]) + jax.random.uniform(key, (2,))  # noqa: E731
    ep = rollout.collect(
        env, go_right, far, jnp.array([[3.0, 0.0]]), 1, jax.random.key(1), switch_every=10
    )
    success, goals = np.asarray(ep.success[0]), np.asarray(ep.goal[0])
    first = int(np.argmax(success))
    assert success.sum() == 1  # only the curriculum goal is ever reached
    assert int(ep.walk_start[0]) == first + 1
    changes = np.flatnonzero(np.any(goals[1:] != goals[:-1], axis=-1)) + 1
    np.testing.assert_array_equal(changes, np.arange(first + 1, env.horizon, 10))
    # Without the timer the first post-success goal holds to the end.
    ep = rollout.collect(env, go_right, far, jnp.array([[3.0, 0.0]]), 1, jax.random.key(1))
    assert len(np.unique(np.asarray(ep.goal[0]), axis=0)) == 2


def test_walk_start_hand_computed():
    success = jnp.array([[0, 0, 1, 0, 1], [0, 0, 0, 0, 0], [1, 0, 0, 0, 0]], bool)
    np.testing.assert_array_equal(rollout.walk_start(success), [3, 5, 1])
