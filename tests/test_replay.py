"""Episode replay buffer: hand-computed wraparound, valid sampling, the recent-episode pool."""

from typing import NamedTuple

import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from d2c_jax.config import ReplayConfig
from d2c_jax.core import replay

H, OBS, ACT, GOAL = 3, 2, 1, 2


class Episodes(NamedTuple):
    obs: jax.Array  # (n, H + 1, OBS)
    achieved_goal: jax.Array  # (n, H + 1, GOAL)
    action: jax.Array  # (n, H, ACT)
    goal: jax.Array  # (n, H, GOAL)


def make_episodes(ids) -> Episodes:
    """Episodes whose every entry encodes (episode id, step): value = 100 * id + t."""
    ids = np.asarray(ids, np.float32)[:, None]
    t = np.arange(H + 1, dtype=np.float32)[None]
    code = 100.0 * ids + t  # (n, H + 1)
    return Episodes(
        obs=jnp.asarray(np.stack([code, -code], -1)),
        achieved_goal=jnp.asarray(np.stack([code, code + 0.5], -1)),
        action=jnp.asarray(code[:, :H, None]),
        goal=jnp.asarray(np.stack([code[:, :H], code[:, :H]], -1) + 0.25),
    )


def fresh(n_slots: int) -> replay.ReplayState:
    return replay.init_replay(ReplayConfig(capacity=n_slots * H + H - 1), OBS, ACT, GOAL, H)


def test_init_shapes_and_capacity_rounding():
    state = replay.init_replay(ReplayConfig(capacity=1050), 6, 2, 2, 100)
    assert state.n_slots == 10 and state.horizon == 100
    chex.assert_shape(state.obs, (10, 101, 6))
    chex.assert_shape(state.achieved_goal, (10, 101, 2))
    chex.assert_shape(state.action, (10, 100, 2))
    chex.assert_shape(state.goal, (10, 100, 2))
    assert int(state.size) == int(state.ptr) == 0
    with pytest.raises(ValueError):
        replay.init_replay(ReplayConfig(capacity=99), 6, 2, 2, 100)


def test_wraparound_overwrites_the_oldest_episodes():
    insert = jax.jit(replay.insert_episodes)
    state = fresh(5)
    state = insert(state, make_episodes([0, 1, 2]))
    assert (int(state.ptr), int(state.size)) == (3, 3)
    state = insert(state, make_episodes([3, 4, 5]))
    # Slots 3, 4 take episodes 3, 4; episode 5 wraps to slot 0, overwriting episode 0.
    assert (int(state.ptr), int(state.size)) == (1, 5)
    np.testing.assert_array_equal(state.obs[:, 0, 0], [500, 100, 200, 300, 400])
    np.testing.assert_array_equal(state.action[:, 2, 0], [502, 102, 202, 302, 402])
    np.testing.assert_array_equal(state.goal[0, :, 0], [500.25, 501.25, 502.25])
    np.testing.assert_array_equal(state.achieved_goal[0, :, 1], [500.5, 501.5, 502.5, 503.5])
    state = insert(state, make_episodes([6, 7]))  # overwrites episodes 1, 2 (the oldest)
    np.testing.assert_array_equal(state.obs[:, 0, 0], [500, 600, 700, 300, 400])
    assert (int(state.ptr), int(state.size)) == (3, 5)


def test_insert_more_than_capacity_raises():
    with pytest.raises(ValueError):
        replay.insert_episodes(fresh(2), make_episodes([0, 1, 2]))


def test_samples_are_valid_transitions_of_filled_slots():
    state = replay.insert_episodes(fresh(5), make_episodes([7, 8]))  # slots 0, 1 filled
    tr = jax.jit(replay.sample, static_argnums=1)(state, 4000, jax.random.key(0))
    ep, t = np.asarray(tr.episode), np.asarray(tr.step)
    assert set(ep) == {0, 1}  # never the unfilled slots 2..4
    assert set(t) == set(range(H))  # t in [0, H): s_{t+1} exists in the episode
    code = np.asarray(tr.obs[:, 0])
    np.testing.assert_array_equal(code, 100 * (7 + ep) + t)
    # s_{t+1}, phi(s_{t+1}) and g_t come from the same episode, one step later / same step.
    np.testing.assert_array_equal(tr.next_obs[:, 0], code + 1)
    np.testing.assert_array_equal(tr.next_obs[:, 1], -(code + 1))
    np.testing.assert_array_equal(tr.next_achieved_goal[:, 0], code + 1)
    np.testing.assert_array_equal(tr.action[:, 0], code)
    np.testing.assert_array_equal(tr.goal[:, 0], code + 0.25)
    # Roughly uniform over the 2 * H valid transitions.
    counts = np.bincount(ep * H + t, minlength=2 * H)
    assert counts.min() > 4000 / (2 * H) * 0.8


def test_samples_after_wraparound_read_only_current_episodes():
    state = fresh(4)
    for ids in ([0, 1, 2], [3, 4, 5]):
        state = replay.insert_episodes(state, make_episodes(ids))
    tr = replay.sample(state, 2000, jax.random.key(1))
    ids = np.asarray(tr.obs[:, 0]) // 100
    assert set(ids.astype(int)) == {2, 3, 4, 5}  # 0 and 1 were overwritten
    np.testing.assert_array_equal(tr.next_obs[:, 0] - tr.obs[:, 0], 1.0)


def test_sample_achieved_goals_covers_every_state_of_filled_slots():
    state = replay.insert_episodes(fresh(5), make_episodes([1, 2]))
    ag = replay.sample_achieved_goals(state, 3000, jax.random.key(2))
    chex.assert_shape(ag, (3000, GOAL))
    codes = np.asarray(ag[:, 0]).astype(int)
    assert set(codes) == {100 * e + t for e in (1, 2) for t in range(H + 1)}


def test_recent_episodes_most_recent_first_with_validity():
    state = replay.insert_episodes(fresh(5), make_episodes([0, 1, 2]))
    slots, valid = replay.recent_episode_slots(state, 4)
    ag = state.achieved_goal[slots]
    chex.assert_shape(ag, (4, H + 1, GOAL))
    np.testing.assert_array_equal(ag[:3, 0, 0], [200, 100, 0])
    np.testing.assert_array_equal(valid, [True, True, True, False])
    state = replay.insert_episodes(state, make_episodes([3, 4, 5]))  # wraps: slot 0 = ep 5
    slots, valid = replay.recent_episode_slots(state, 5)
    ag = state.achieved_goal[slots]
    np.testing.assert_array_equal(ag[:, 0, 0], [500, 400, 300, 200, 100])
    np.testing.assert_array_equal(ag[0, :, 1], [500.5, 501.5, 502.5, 503.5])
    assert bool(valid.all())
    with pytest.raises(ValueError):
        replay.recent_episode_slots(state, 6)


def test_insert_traces_once_and_vmaps_over_seeds():
    insert = jax.jit(chex.assert_max_traces(replay.insert_episodes, n=1))
    state = fresh(4)
    for ids in ([0, 1], [2, 3], [4, 5]):
        state = insert(state, make_episodes(ids))
    np.testing.assert_array_equal(state.obs[:, 0, 0], [400, 500, 200, 300])
    seeds = jax.tree.map(lambda x: jnp.stack([x, x]), fresh(4))
    eps = jax.tree.map(lambda x: jnp.stack([x, x + 1000]), make_episodes([0, 1]))
    both = jax.vmap(replay.insert_episodes)(seeds, eps)
    np.testing.assert_array_equal(both.obs[:, :2, 0, 0], [[0, 100], [1000, 1100]])


class PhasedEpisodes(NamedTuple):
    obs: jax.Array
    achieved_goal: jax.Array
    action: jax.Array
    goal: jax.Array
    walk_start: jax.Array  # (n,) int32


def phased_buffer():
    """4 of 6 slots filled; walk_start 1, 3 (= H: no walk), 0 (all walk), 2."""
    state = fresh(6)
    walk_start = jnp.asarray([1, 3, 0, 2], jnp.int32)
    return replay.insert_episodes(state, PhasedEpisodes(*make_episodes(range(4)), walk_start))


def test_phase_split_batches_and_uniform_within_each_phase():
    state = phased_buffer()
    tr = jax.jit(replay.sample, static_argnums=(1, 3))(state, 4000, jax.random.key(0), 0.25)
    ep, t = np.asarray(tr.episode), np.asarray(tr.step)
    walk_start = np.asarray(state.walk_start)[ep]
    main, walk = slice(0, 3000), slice(3000, 4000)
    assert np.all(t[main] < walk_start[main]) and np.all(t[walk] >= walk_start[walk])
    assert np.all(ep < 4)
    # Curriculum phase: (0,0) (1,0) (1,1) (1,2) (3,0) (3,1); random walk: (0,1) (0,2)
    # (2,0) (2,1) (2,2) (3,2): six transitions each, each drawn ~1/6 of its share.
    for part, n in ((main, 3000), (walk, 1000)):
        _, counts = np.unique(ep[part] * 10 + t[part], return_counts=True)
        assert len(counts) == 6
        np.testing.assert_allclose(counts / n, 1 / 6, atol=0.035)
    # The same transitions as Transition rows: obs codes 100 * episode + t.
    np.testing.assert_array_equal(np.asarray(tr.obs)[:, 0], 100 * ep + t)


def test_phase_sampling_falls_back_to_all_transitions_without_a_walk():
    state = replay.insert_episodes(fresh(6), make_episodes(range(2)))  # no walk_start field
    np.testing.assert_array_equal(state.walk_start[:2], [H, H])
    tr = replay.sample(state, 400, jax.random.key(1), walk_fraction=0.5)
    assert set(np.unique(np.asarray(tr.step)).tolist()) == {0, 1, 2}


def test_negatives_from_the_curriculum_phase_only():
    state = phased_buffer()
    ag = np.asarray(replay.sample_achieved_goals(state, 3000, jax.random.key(2), True))[:, 0]
    ep, t = ag // 100, ag % 100
    # States s_0..s_{walk_start}: slot 0 t <= 1, slot 1 all 4, slot 2 s_0, slot 3 t <= 2.
    limit = np.asarray([1, 3, 0, 2])[ep.astype(int)]
    assert np.all(t <= limit) and len(np.unique(ag)) == 2 + 4 + 1 + 3


def test_archive_draws_distinct_filled_episodes():
    state = phased_buffer()
    slots, valid = replay.archived_episode_slots(state, 4, jax.random.key(3))
    ag = state.achieved_goal[slots]
    assert np.all(valid)
    assert sorted((np.asarray(ag)[:, 0, 0] // 100).tolist()) == [0, 1, 2, 3]
    slots, valid = replay.archived_episode_slots(state, 6, jax.random.key(3))
    assert int(np.asarray(valid).sum()) == 4  # two rows beyond the stored episodes
    with pytest.raises(ValueError, match="archive"):
        replay.archived_episode_slots(state, 7, jax.random.key(3))


def test_weighted_archive_draws_in_proportion_to_the_weights():
    """Slot weights 1 : 3 (a = 1 draw): over many keys slot 1 comes three times as often;
    a weight of -inf is never drawn while others are left; empty slots never are."""
    state = phased_buffer()  # 4 of 6 slots filled
    log_w = jnp.log(jnp.asarray([1.0, 3.0, 0.0, 0.0, 5.0, 5.0]))  # slots 4, 5 are empty
    draw = jax.jit(jax.vmap(lambda k: replay.archived_episode_slots(state, 1, k, log_w)[0][0]))
    picks = np.asarray(draw(jax.random.split(jax.random.key(0), 4000)))
    counts = np.bincount(picks, minlength=6)
    assert counts[2] == counts[3] == counts[4] == counts[5] == 0
    np.testing.assert_allclose(counts[1] / counts[0], 3.0, rtol=0.12)
    slots, valid = replay.archived_episode_slots(state, 4, jax.random.key(1), log_w)
    assert np.all(valid) and sorted(np.asarray(slots).tolist()) == [0, 1, 2, 3]


def test_hold_after_repeats_the_state_at_stop_hand_computed():
    # Two trajectories of 5 steps (values 0..4 and 5..9); stop 2 and 4 (nothing held).
    x = jnp.arange(10.0).reshape(2, 5, 1)
    held = replay.hold_after(x, jnp.asarray([2, 4]))
    np.testing.assert_array_equal(held[..., 0], [[0, 1, 2, 2, 2], [5, 6, 7, 8, 9]])
    # Trailing feature axes travel with their step.
    xy = jnp.stack([x[..., 0], -x[..., 0]], -1)
    np.testing.assert_array_equal(replay.hold_after(xy, jnp.asarray([0, 1]))[1, 3], [6, -6])
