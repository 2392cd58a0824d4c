"""HER 'future' relabelling: same episode, later steps only, ~80 %, rewards recomputed;
the optional 'random' strategy's share and source."""

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from d2c_jax.config import HERConfig, ReplayConfig
from d2c_jax.core import her, replay

H = 5
STORED_GOAL = -7.0  # never an achieved goal, so relabelled goals are recognisable


class Episodes(NamedTuple):
    obs: jax.Array
    achieved_goal: jax.Array
    action: jax.Array
    goal: jax.Array


def buffer_with(ids, n_slots=6) -> replay.ReplayState:
    """Episodes where obs[e, t] = ag[e, t] = (100 * id + t, id); stored goals = STORED_GOAL."""
    ids = np.asarray(ids, np.float32)
    code = 100.0 * ids[:, None] + np.arange(H + 1, dtype=np.float32)[None]  # (n, H + 1)
    pair = np.stack([code, np.broadcast_to(ids[:, None], code.shape)], -1)
    eps = Episodes(
        obs=jnp.asarray(pair),
        achieved_goal=jnp.asarray(pair),
        action=jnp.zeros((len(ids), H, 1)),
        goal=jnp.full((len(ids), H, 2), STORED_GOAL),
    )
    state = replay.init_replay(ReplayConfig(capacity=n_slots * H), 2, 1, 2, H)
    return replay.insert_episodes(state, eps)


def reward_first_coordinate(ag_next, goal):
    """A reward that identifies its inputs: ag_next[0] - 1000 * goal[0]."""
    return ag_next[..., 0] - 1000.0 * goal[..., 0]


@pytest.fixture(scope="module")
def big_batch():
    state = buffer_with([3, 4, 5])
    relabel = jax.jit(her.relabel, static_argnums=(0, 2, 3))
    return relabel(
        HERConfig().relabel_prob, state, 20_000, reward_first_coordinate, jax.random.key(0)
    )


def test_relabelled_goals_come_from_later_steps_of_the_same_episode(big_batch):
    b = big_batch
    relabelled = np.asarray(b.goal[:, 0] != STORED_GOAL)
    ep_id, t = np.asarray(b.obs[:, 1]), np.asarray(b.obs[:, 0]) % 100
    goal_id, t_future = np.asarray(b.goal[:, 1]), np.asarray(b.goal[:, 0]) % 100
    np.testing.assert_array_equal(goal_id[relabelled], ep_id[relabelled])
    assert np.all(t_future[relabelled] >= t[relabelled] + 1)
    assert np.all(t_future[relabelled] <= H)
    # t' is uniform in [t + 1, H]: for t = 0 every future step 1..H appears, about equally.
    from_start = relabelled & (t == 0)
    counts = np.bincount(t_future[from_start].astype(int), minlength=H + 1)[1:]
    assert counts.min() > 0.7 * counts.mean()
    # The last transition (t = H - 1) can only take the final achieved goal.
    last = relabelled & (t == H - 1)
    assert last.any() and np.all(t_future[last] == H)
    # Not relabelled: the goal active at step t is kept.
    np.testing.assert_array_equal(b.goal[~relabelled], STORED_GOAL)


def test_about_eighty_percent_relabelled(big_batch):
    frac = float(np.mean(np.asarray(big_batch.goal[:, 0] != STORED_GOAL)))
    assert abs(frac - 0.8) < 0.015  # 20k Bernoulli(0.8): std 0.003


def test_rewards_are_recomputed_on_next_achieved_goal_and_final_goal(big_batch):
    b = big_batch
    next_ag = np.asarray(b.next_obs[:, 0])  # obs and achieved goals coincide here
    np.testing.assert_array_equal(next_ag, np.asarray(b.obs[:, 0]) + 1)
    expected = next_ag - 1000.0 * np.asarray(b.goal[:, 0])
    np.testing.assert_allclose(b.reward, expected, rtol=1e-6)
    np.testing.assert_array_equal(b.mask, 1.0)  # no terminal on success (SPEC §4)
    assert b.reward.shape == b.mask.shape == (20_000,)


@pytest.mark.parametrize("prob, expected", [(0.0, 0.0), (1.0, 1.0)])
def test_relabel_probability_extremes(prob, expected):
    b = her.relabel(
        prob, buffer_with([1]), 500, reward_first_coordinate,
        jax.random.key(1),
    )  # fmt: skip
    assert float(np.mean(np.asarray(b.goal[:, 0] != STORED_GOAL))) == expected


def test_future_goals_already_reached_at_s_t_are_not_used():
    """min_distance 2.5 on episodes whose phi moves 1 per step: a future goal t' - t < 3
    steps ahead is within 2.5 of phi(s_t), so the transition keeps its stored goal. With t'
    uniform in [t + 1, H] (H = 5) the share still relabelled is, by hand, 3/5 at t = 0, 2/4
    at t = 1, 1/3 at t = 2 and 0 at t = 3, 4."""
    tr = her.sample_relabelled(1.0, buffer_with([1, 2]), 40_000, jax.random.key(2), 0.0, 2.5)
    relabelled = np.asarray(tr.goal[:, 0] != STORED_GOAL)
    t = np.asarray(tr.obs[:, 0]) % 100
    ahead = np.asarray(tr.goal[:, 0]) % 100 - t
    assert np.all(ahead[relabelled] >= 3)
    for step, share in enumerate([3 / 5, 2 / 4, 1 / 3, 0.0, 0.0]):
        np.testing.assert_allclose(np.mean(relabelled[t == step]), share, atol=0.02)


def test_random_strategy_takes_its_share_from_the_whole_buffer():
    """relabel_prob 0.5 and random_prob 0.3 on three episodes of ids 3, 4, 5: 20% keep the
    stored goal; a random goal is phi of a state uniform over the 3 x (H + 1) stored ones,
    so by hand 0.3 * 2/3 = 0.2 of the batch gets another episode's state (future goals
    never do) and 0.3 * 1/6 = 0.05 a step-0 state (future goals start at t + 1)."""
    tr = her.sample_relabelled(
        0.5, buffer_with([3, 4, 5]), 40_000, jax.random.key(3), 0.0, 0.0, 0.3
    )
    goal, obs = np.asarray(tr.goal), np.asarray(tr.obs)
    kept = goal[:, 0] == STORED_GOAL
    np.testing.assert_allclose(kept.mean(), 0.2, atol=0.01)  # std 0.002
    other_episode = ~kept & (goal[:, 1] != obs[:, 1])
    np.testing.assert_allclose(other_episode.mean(), 0.2, atol=0.01)
    step_zero = ~kept & (goal[:, 0] % 100 == 0)
    np.testing.assert_allclose(step_zero.mean(), 0.05, atol=0.006)
    # Every stored state can be drawn, from every episode.
    assert {(int(g[1]), int(g[0]) % 100) for g in goal[~kept]} == {
        (e, t) for e in (3, 4, 5) for t in range(H + 1)
    }


def test_random_strategy_off_is_the_future_only_program():
    state, key = buffer_with([3, 4, 5]), jax.random.key(4)
    default = her.sample_relabelled(0.8, state, 1000, key)
    off = her.sample_relabelled(0.8, state, 1000, key, 0.0, 0.0, 0.0)
    np.testing.assert_array_equal(default.goal, off.goal)
    both = her.sample_relabelled(0.8, state, 1000, key, 0.0, 0.0, 0.2)
    # The future coin is the same draw: only transitions it left alone change.
    future = np.asarray(default.goal[:, 0] != STORED_GOAL)
    np.testing.assert_array_equal(both.goal[future], default.goal[future])
    assert np.all(np.asarray(both.goal[:, 0]) != STORED_GOAL)  # 0.8 + 0.2: none kept


class RadiusEnv:
    success_radius = 0.5

    def is_success(self, ag, g):
        return jnp.linalg.norm(ag - g, axis=-1) <= self.success_radius


def test_sparse_reward_fn():
    reward_fn = her.sparse_reward_fn(RadiusEnv())
    ag = jnp.array([[0.0, 0.0], [0.3, 0.4], [0.3, 0.41], [5.0, 5.0]])
    np.testing.assert_array_equal(reward_fn(ag, jnp.zeros(2)), [1.0, 1.0, 0.0, 0.0])


def test_sparse_reward_with_her_rewards_reached_future_goals():
    """With the sparse reward, relabelling to t' = t + 1 always pays 1."""
    state = buffer_with([2])
    reward_fn = her.sparse_reward_fn(RadiusEnv())
    b = her.relabel(1.0, state, 2000, reward_fn, jax.random.key(2))
    next_step = np.asarray(b.goal[:, 0]) == np.asarray(b.next_obs[:, 0])
    np.testing.assert_array_equal(np.asarray(b.reward)[next_step], 1.0)
    np.testing.assert_array_equal(np.asarray(b.reward)[~next_step], 0.0)


def test_terminal_fn_masks_the_bootstrap_where_the_relabelled_goal_is_reached():
    """OUTPACE's critic stops at success of the (relabelled) goal: mask = 1 - success, by
    hand on four transitions; the reward is untouched, and without terminal_fn the mask
    is 1 everywhere (SPEC §4)."""
    ag_next = jnp.array([[0.0, 0.0], [0.3, 0.4], [0.3, 0.41], [5.0, 5.0]])
    goal = jnp.zeros((4, 2))
    tr = her.RelabelledTransitions(
        obs=jnp.zeros((4, 1)), action=jnp.zeros((4, 1)), next_obs=jnp.zeros((4, 1)),
        next_achieved_goal=ag_next, goal=goal,
    )  # fmt: skip
    terminal = her.with_reward(tr, reward_first_coordinate, her.sparse_reward_fn(RadiusEnv()))
    np.testing.assert_array_equal(terminal.mask, [0.0, 0.0, 1.0, 1.0])
    np.testing.assert_allclose(terminal.reward, [0.0, 0.3, 0.3, 5.0])
    np.testing.assert_array_equal(her.with_reward(tr, reward_first_coordinate).mask, 1.0)


def time_index_reward(ag_next, goal):
    """The step t' of phi(s_t') in `buffer_with`'s code (100 id + t', id); goal unused."""
    return ag_next[..., 0] - 100.0 * ag_next[..., 1] + 0.0 * goal[..., 0]


def test_n_step_rows_sum_the_next_rewards_up_to_the_episode_end():
    """n = 3, H = 5: row t sums gamma^k (t + k + 1) over k < n' = min(3, 5 - t), its
    bootstrap state is s_{t+n'} with weight gamma^(n'-1), by hand for every t."""
    gamma, n = 0.9, 3
    state = buffer_with([2])
    tr = her.sample_relabelled(0.0, state, 400, jax.random.key(3), n_step=n)
    b = her.with_reward(tr, time_index_reward, gamma=gamma)
    t = np.asarray(b.obs[:, 0]).astype(int) % 100
    assert set(t.tolist()) == set(range(H))
    n_taken = np.minimum(n, H - t)
    k = np.arange(n)[None]  # (1, n)
    expected = np.sum(np.where(k < n_taken[:, None], gamma**k * (t[:, None] + k + 1), 0), 1)
    np.testing.assert_allclose(b.reward, expected, rtol=1e-6)
    np.testing.assert_allclose(b.mask, gamma ** (n_taken - 1.0), rtol=1e-6)
    np.testing.assert_array_equal(np.asarray(b.next_obs[:, 0]) % 100, t + n_taken)
    np.testing.assert_array_equal(b.goal, STORED_GOAL)  # relabel_prob 0 keeps the goal


def test_n_step_relabelled_goals_are_rewarded_along_the_whole_path():
    """With relabel_prob 1 every goal is a later step t'' of the same episode, and row t
    pays sum_k gamma^k r(phi(s_{t+k+1}), g) with the relabelled g: checked against the
    goal-dependent reward of `reward_first_coordinate`."""
    gamma, n = 0.5, 2
    state = buffer_with([3])
    tr = her.sample_relabelled(1.0, state, 200, jax.random.key(4), n_step=n)
    b = her.with_reward(tr, reward_first_coordinate, gamma=gamma)
    t, g = np.asarray(b.obs[:, 0]) % 100, np.asarray(b.goal[:, 0])
    n_taken = np.minimum(n, H - t)
    r = lambda k: 300.0 + t + k + 1 - 1000.0 * g  # noqa: E731
    expected = r(0) + np.where(n_taken > 1, gamma * r(1), 0.0)
    np.testing.assert_allclose(b.reward, expected, rtol=1e-6)


def test_n_step_return_stops_at_a_terminal():
    """Terminals inside the n steps end the sum and zero the bootstrap, by hand: rewards
    1, 2, 3 with a terminal at the second step give 1 + gamma 2 and mask 0; without one,
    1 + gamma 2 + gamma^2 3 and mask gamma^2; rows cut to n' = 1 and 2 keep their first
    one and two steps."""
    gamma = 0.5
    path = jnp.array([[[1.0, 9.0], [2.0, 0.0], [3.0, 9.0]]] * 3)  # (3 rows, n = 3, 2)
    tr = her.RelabelledTransitions(
        obs=jnp.zeros((3, 1)), action=jnp.zeros((3, 1)), next_obs=jnp.zeros((3, 1)),
        next_achieved_goal=path[:, 0], goal=jnp.zeros((3, 2)), path_achieved_goal=path,
        n_taken=jnp.array([3, 1, 2]),
    )  # fmt: skip
    first = lambda ag, g: ag[..., 0]  # noqa: E731
    at_zero = lambda ag, g: ag[..., 1] == 0.0  # noqa: E731 terminal at the second step
    b = her.with_reward(tr, first, at_zero, gamma=gamma)
    np.testing.assert_allclose(b.reward, [1 + gamma * 2, 1.0, 1 + gamma * 2])
    np.testing.assert_allclose(b.mask, [0.0, 1.0, 0.0])
    free = her.with_reward(tr, first, gamma=gamma)
    np.testing.assert_allclose(free.reward, [1 + gamma * 2 + gamma**2 * 3, 1.0, 1 + gamma * 2])
    np.testing.assert_allclose(free.mask, [gamma**2, 1.0, gamma])
