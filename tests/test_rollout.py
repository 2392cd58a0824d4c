"""The episode loop (`rollout.run`) and what is built on it (collection, evaluation,
trajectories for rendering) on the medium maze with scripted policies."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from d2c_jax.core import rollout


def go_right(obs, goal, key):
    """Full speed along +x (heading starts near 0)."""
    return jnp.array([1.0, -obs[2]])


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


def test_stayed_at_start_hand_computed():
    # Radius 1: episode 0 wanders to distance 0.6 and back; episode 1 reaches exactly 1.0
    # (inside: the success test is <= radius too); episode 2 passes 1.5 and returns.
    ag = jnp.array(
        [
            [[2.0, 2.0], [2.6, 2.0], [2.0, 2.0]],
            [[0.0, 0.0], [0.0, 1.0], [0.0, 0.5]],
            [[0.0, 0.0], [0.0, -1.5], [0.0, 0.0]],
        ]
    )
    np.testing.assert_array_equal(rollout.stayed_at_start(ag, 1.0), [True, True, False])
    np.testing.assert_array_equal(rollout.stayed_at_start(ag, 0.5), [False, False, False])


def test_trajectories_start_at_the_reset_state_and_take_any_number_of_steps(medium_maze):
    env = medium_maze
    goals = jnp.asarray(env.goal_points[:3])
    key = jax.random.key(4)
    tr = jax.jit(lambda g, k: rollout.trajectories(env, go_right, g, k, steps=4))(goals, key)
    assert tr.qpos.shape == (3, 5, 3) and tr.mocap_pos.shape == (3, 5, 0, 3)
    assert tr.goal.shape == (3, 5, 2) and tr.success.shape == (3, 5)
    assert tr.achieved_goal.shape == (3, 5, 2)
    np.testing.assert_array_equal(tr.goal, np.broadcast_to(goals[:, None], (3, 5, 2)))
    key_reset, _ = rollout.episode_keys(jax.random.split(key, 3), 4)
    reset = jax.vmap(env.reset_with_goal)(key_reset, goals)
    np.testing.assert_array_equal(tr.qpos[:, 0], reset.data.qpos)
    np.testing.assert_array_equal(tr.achieved_goal, tr.qpos[..., :2])
    assert (np.diff(tr.qpos[:, :, 0], axis=1) > 0.5).all()  # it goes right, step after step


# Post-success goals far off: only a curriculum goal is ever reached, then the timer
# switches goals (the goal switch draws keys too).
far = lambda ag, key: ag + jnp.array([0.0, 100.0]) + jax.random.uniform(key, (2,))  # noqa: E731


@pytest.mark.parametrize("switching", [False, True])
def test_trajectories_play_collects_episodes(medium_maze, switching):
    """Same goals and key: the rendering trajectories are the training episodes, with and
    without goal switching (a state's goal is the one pursued when it was reached)."""
    env = medium_maze
    if switching:  # envs 0 and 2 reach (3, 0) and then switch; env 1 never does
        policy, goals = go_right, jnp.array([[3.0, 0.0], [100.0, 100.0], [3.0, 0.0]])
        switch = dict(next_goal=far, switch_every=10)
    else:  # random actions, unreachable goals: no env ever switches
        policy, goals = rollout.random_policy(2), jnp.array([[100.0, 100.0], [-100.0, 0.0]])
        switch = {}
    key = jax.random.key(5)
    ep = rollout.collect(env, policy, far, goals, len(goals), key, switch.get("switch_every", 0))
    tr = rollout.trajectories(env, policy, goals, key, **switch)
    np.testing.assert_array_equal(tr.achieved_goal, ep.achieved_goal)
    np.testing.assert_array_equal(tr.goal[:, 1:], ep.goal)
    np.testing.assert_array_equal(tr.success[:, 1:], ep.success)
    np.testing.assert_array_equal(tr.goal[:, 0], goals)
    changed = (np.asarray(ep.goal)[:, 1:] != np.asarray(ep.goal)[:, :-1]).any(axis=(1, 2))
    np.testing.assert_array_equal(changed, [switching, False, switching][: len(goals)])


def test_evaluate_scores_the_episodes_of_the_loop(medium_maze):
    """evaluate(key) = success at any step of trajectories(modes repeated, key)."""
    env = medium_maze
    # The oracle for the upper modes; standing still (never a success) for the lower ones.
    policy = lambda obs, goal, key: jnp.where(goal[1] > 0, oracle(obs, goal, key), 0.0)  # noqa: E731
    key = jax.random.key(6)
    score = jax.jit(lambda k: rollout.evaluate(env, policy, 2, k))(key)
    goals = jnp.repeat(jnp.asarray(env.goal_points), 2, axis=0)
    tr = rollout.trajectories(env, policy, goals, key)
    hit = np.asarray(tr.success[:, 1:]).any(axis=1).reshape(4, 2).mean(axis=1)
    np.testing.assert_array_equal(score, hit)
    np.testing.assert_array_equal(score, (np.asarray(env.goal_points)[:, 1] > 0).astype(float))


def test_episodes_in_batches_equal_one_batch(medium_maze):
    """`in_batches` (lax.map over batches, the last one padded) gives every episode what
    one batch gives it: each keeps its own key. Random actions make every episode differ."""
    env = medium_maze
    noisy = lambda obs, goal, key: jax.random.uniform(key, (2,), minval=-1, maxval=1)  # noqa: E731
    record = lambda before, action, after: (after.achieved_goal, after.success)  # noqa: E731

    def play(goals, env_keys):
        return rollout.run_with_env_keys(env, noisy, goals, env_keys, record=record, steps=20)[1]

    goals = jnp.repeat(jnp.asarray(env.goal_points), 2, axis=0)[:7]  # 7 = 3 + 3 + 1 padded
    env_keys = jax.random.split(jax.random.key(5), 7)
    whole = jax.jit(lambda g, k: rollout.in_batches(play, g, k, 100))(goals, env_keys)
    batched = jax.jit(lambda g, k: rollout.in_batches(play, g, k, 3))(goals, env_keys)
    assert batched[0].shape == (7, 20, 2) and batched[1].shape == (7, 20)
    assert np.ptp(np.asarray(whole[0])[:, -1], axis=0).min() > 0.1  # the episodes differ
    np.testing.assert_allclose(batched[0], whole[0], rtol=0, atol=1e-5)
    np.testing.assert_array_equal(batched[1], whole[1])
    # run(key) is run_with_env_keys with split(key, n)
    _, by_key = rollout.run(env, noisy, goals, jax.random.key(5), record=record, steps=20)
    np.testing.assert_allclose(by_key[0], whole[0], rtol=0, atol=1e-5)


def test_success_rates_in_batches_equal_one_batch(medium_maze):
    """The evaluation's score does not depend on how many episodes run at once."""
    env = medium_maze
    policy = lambda obs, goal, key: jnp.where(goal[1] > 0, oracle(obs, goal, key), 0.0)  # noqa: E731
    goals, key = jnp.asarray(env.goal_points), jax.random.key(6)
    scores = [
        jax.jit(lambda k, b=b: rollout.success_rates(env, policy, goals, 2, k, max_batch=b))(key)
        for b in (100, 3)
    ]
    np.testing.assert_array_equal(scores[1], scores[0])
    np.testing.assert_array_equal(scores[0], (np.asarray(env.goal_points)[:, 1] > 0).astype(float))


@pytest.mark.parametrize("switching", [False, True])
def test_collect_in_batches_equals_one_batch(medium_maze, switching):
    """Training episodes played 3 at a time (`collect`'s max_batch: 7 = 3 + 3 + 1 padded)
    are the episodes of one batch, goal switches and their keys included."""
    env = medium_maze
    noisy = lambda obs, goal, key: jax.random.uniform(key, (2,), minval=-1, maxval=1)  # noqa: E731
    policy = go_right if switching else noisy
    goals = jnp.array([[3.0, 0.0], [100.0, 100.0], [3.0, 0.0]])
    key = jax.random.key(8)
    episodes = [
        jax.jit(lambda k, b=b: rollout.collect(env, policy, far, goals, 7, k, 10, max_batch=b))(key)
        for b in (None, 3)
    ]
    switched = (np.asarray(episodes[0].goal)[:, 1:] != np.asarray(episodes[0].goal)[:, :-1]).any()
    assert switched == switching
    for one, batched in zip(*map(jax.tree.leaves, episodes), strict=True):
        assert one.shape == batched.shape
        np.testing.assert_allclose(np.asarray(batched), np.asarray(one), rtol=0, atol=1e-5)


def test_episodes_per_call_are_capped_on_cpu_only():
    """`MAX_CPU_ENV_BATCH` env states per call on CPU, shared by the runs vmapped together
    (at least one episode each); no cap on an accelerator."""
    cap = rollout.MAX_CPU_ENV_BATCH
    assert rollout.max_episodes_per_call("cpu", 1) == cap
    assert rollout.max_episodes_per_call("cpu", 3) == cap // 3
    assert rollout.max_episodes_per_call("cpu", 10 * cap) == 1
    assert rollout.max_episodes_per_call("gpu", 64) is None


def test_run_records_what_it_is_told(medium_maze):
    """run(record=...) keeps per step what record(before, action, after) returns."""
    env = medium_maze
    goals = jnp.array([[100.0, 100.0], [-100.0, 0.0]])
    record = lambda before, action, after: (action, after.obs[:2] - before.obs[:2])  # noqa: E731
    first, (action, moved) = rollout.run(
        env, go_right, goals, jax.random.key(0), record=record, steps=3
    )
    np.testing.assert_array_equal(first.goal, goals)
    assert action.shape == (2, 3, 2) and moved.shape == (2, 3, 2)
    np.testing.assert_array_equal(action[..., 0], np.ones((2, 3)))
    np.testing.assert_allclose(np.linalg.norm(moved, axis=-1), 1.0, atol=0.05)
