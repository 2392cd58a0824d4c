"""envs.to_brax: brax's wrappers and trainers on our goal envs (envs/brax_adapter.py)."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs
from benchmarks import brax_compat
from d2c_jax.core import networks


@pytest.fixture(scope="module")
def adapter(medium_maze):
    return envs.to_brax(medium_maze)


def test_sizes_and_backend(adapter, medium_maze):
    from brax.envs.base import Env

    assert isinstance(adapter, Env)
    assert adapter.observation_size == networks.feature_dim(medium_maze) == 7 + 2
    assert adapter.action_size == medium_maze.action_dim == 2
    assert adapter.backend == "mjx"


def test_obs_is_our_features_and_reward_is_success_by_hand(adapter, medium_maze):
    """A still step (zero action: no turn, no move) from a known pose, with the goal 0.3
    from the agent (inside the 0.5 radius) and then 0.7 from it (outside)."""
    env = medium_maze
    np.testing.assert_array_equal([env.goal_low, env.goal_high], [[-18, -18], [18, 18]])
    start = adapter.reset(jax.random.PRNGKey(3))
    pose = np.asarray(start.pipeline_state.obs[:3], np.float64)  # x, y, heading
    step = jax.jit(adapter.step)
    for offset, reward in ((0.3, 1.0), (0.7, 0.0)):
        goal = np.float32(pose[:2] + [0.0, offset])
        state = start.replace(pipeline_state=env.set_goal(start.pipeline_state, goal))
        after = step(state, jnp.zeros(2))
        # Hand-made features: goal bounds [-18, 18]^2 -> [-1, 1], heading as (sin, cos),
        # speeds 0 (the agent did not move), then the goal scaled like xy.
        want = np.concatenate([pose[:2] / 18, np.sin(pose[2:]), np.cos(pose[2:]), [0, 0, 0]])
        want = np.concatenate([want, goal / 18])
        np.testing.assert_allclose(after.obs, want, atol=1e-6)
        ours = networks.actor_input(env, after.pipeline_state.obs, goal)
        np.testing.assert_allclose(after.obs, ours, rtol=1e-6, atol=1e-7)  # jit vs eager
        assert float(after.reward) == reward == float(after.metrics["success"])
        assert float(after.done) == 0.0


def test_brax_wrappers_vmap_truncate_at_the_horizon_and_auto_reset(adapter, medium_maze):
    from brax.envs.wrappers import training

    env, n, horizon = medium_maze, 3, medium_maze.horizon
    wrapped = training.wrap(adapter, episode_length=horizon)
    first = jax.jit(wrapped.reset)(jax.random.split(jax.random.PRNGKey(0), n))

    @jax.jit
    def play(state, key):
        def body(state, key):
            action = jax.random.uniform(key, (n, env.action_dim), minval=-1, maxval=1)
            state = wrapped.step(state, action)
            out = (state.done, state.info["truncation"], state.info["steps"], state.reward)
            return state, (*out, state.obs, state.pipeline_state.goal, state.pipeline_state)

        return jax.lax.scan(body, state, jax.random.split(key, horizon + 1))

    last, (done, trunc, steps, reward, obs, goal, traj) = play(first, jax.random.PRNGKey(1))
    # Goals are mode points, one per env, kept through the reset (brax replays the slot's
    # first state); obs is always the features of the state brax carries.
    modes = np.asarray(env.goal_points)
    assert all(
        np.min(np.abs(modes - g).sum(-1)) == 0 for g in np.asarray(first.pipeline_state.goal)
    )
    np.testing.assert_array_equal(goal, np.broadcast_to(first.pipeline_state.goal, goal.shape))
    np.testing.assert_allclose(obs, features(env, traj), rtol=1e-6, atol=1e-7)  # jit vs eager
    np.testing.assert_array_equal(reward, traj.success.astype(np.float32))
    # done only at step H, as a truncation; then the step count restarts.
    want_done = np.zeros((horizon + 1, n))
    want_done[horizon - 1] = 1
    np.testing.assert_array_equal(done, want_done)
    np.testing.assert_array_equal(trunc, want_done)
    np.testing.assert_array_equal(steps[:, 0], [*range(1, horizon + 1), 1])
    # At step H the state is the first one again, leaf for leaf.
    at_reset = jax.tree.map(lambda x: x[horizon - 1], traj)
    for a, b in zip(jax.tree.leaves(at_reset), jax.tree.leaves(first.pipeline_state), strict=True):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(obs[horizon - 1], first.obs)
    assert not np.array_equal(obs[horizon - 2], first.obs)
    np.testing.assert_allclose(
        last.info["episode_metrics"]["sum_reward"], reward[horizon:].sum(0), atol=0
    )


def features(env, states):
    """The features of (a batch of) EnvStates, as our agent computes them."""
    return networks.actor_input(env, states.obs, states.goal)


def tiny_sac(env, **overrides):
    """brax SAC with 16-unit networks: a few hundred env steps, one evaluation."""
    from brax.training.agents.sac import networks as sac_networks
    from brax.training.agents.sac import train as sac_train

    brax_compat.install()
    kwargs = dict(
        num_timesteps=256,
        episode_length=env.horizon,
        num_envs=4,
        num_eval_envs=2,
        batch_size=32,
        grad_updates_per_step=4,
        min_replay_size=64,
        num_evals=1,
        network_factory=functools.partial(
            sac_networks.make_sac_networks, hidden_layer_sizes=(16, 16)
        ),
    )
    return sac_train.train(envs.to_brax(env), **{**kwargs, **overrides})


def tiny_ppo(env):
    """brax PPO with 16-unit networks: one short unroll, one evaluation."""
    from brax.training.agents.ppo import networks as ppo_networks
    from brax.training.agents.ppo import train as ppo_train

    brax_compat.install()
    factory = functools.partial(
        ppo_networks.make_ppo_networks,
        policy_hidden_layer_sizes=(16, 16),
        value_hidden_layer_sizes=(16, 16),
    )
    return ppo_train.train(
        envs.to_brax(env),
        num_timesteps=64,
        episode_length=env.horizon,
        num_envs=4,
        num_eval_envs=2,
        batch_size=4,
        num_minibatches=1,
        unroll_length=4,
        num_updates_per_batch=1,
        num_evals=1,
        network_factory=factory,
    )


def assert_finite(params, metrics):
    leaves = jax.tree.leaves(params)
    assert leaves and all(np.all(np.isfinite(np.asarray(x))) for x in leaves)
    assert metrics and all(np.isfinite(float(v)) for v in metrics.values())


@pytest.mark.slow  # compiles brax's SAC (~19 s on 2 cores); the wrappers above stay default
def test_brax_sac_trains_on_a_maze(medium_maze):
    """A few hundred env steps of brax's SAC through the adapter: finite params and
    metrics, the evaluation's success counted from our reward."""
    make_policy, params, metrics = tiny_sac(medium_maze)
    assert_finite(params, metrics)
    assert "eval/episode_success" in metrics
    obs = jnp.zeros((1, networks.feature_dim(medium_maze)))
    action, _ = make_policy(params, deterministic=True)(obs, jax.random.PRNGKey(0))
    assert action.shape == (1, medium_maze.action_dim)


@pytest.mark.slow
@pytest.mark.parametrize("name", envs.ENV_NAMES)
def test_brax_sac_and_ppo_start_on_every_env(name):
    env = envs.make(name)
    assert_finite(*tiny_sac(env, num_timesteps=128)[1:])
    assert_finite(*tiny_ppo(env)[1:])
