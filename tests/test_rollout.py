"""Episode collection and evaluation on the medium maze with scripted policies."""

import jax
import jax.numpy as jnp
import numpy as np

from d2c_jax import rollout


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
