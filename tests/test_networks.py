"""Actor / twin critic: smooth log-std squashing, stable tanh log-det, stacked critics."""

import dataclasses
import math

import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from d2c_jax.config import SACConfig
from d2c_jax.core import networks


class StubEnv:
    """Minimal goal-env contract: obs (3,) -> features (4,), goal (2,)."""

    obs_dim, action_dim, goal_dim = 3, 2, 2

    def normalize_obs(self, obs):
        return jnp.concatenate([obs / 10.0, jnp.sin(obs[..., :1])], axis=-1)

    def normalize_goal(self, goal):
        return goal / 5.0

    def goal_of_obs(self, obs):
        return obs[..., 1:3]


CFG = SACConfig(hidden_sizes=(32, 32))


@pytest.fixture(scope="module")
def nets():
    return networks.make_networks(CFG, StubEnv())


def test_actor_input_concatenates_normalised_obs_and_goal():
    env = StubEnv()
    obs = jnp.arange(3.0)
    goal = jnp.array([5.0, -10.0])
    feats = networks.actor_input(env, obs, goal)
    np.testing.assert_allclose(feats, [0.0, 0.1, 0.2, 0.0, 1.0, -2.0], rtol=1e-6)
    assert networks.feature_dim(env) == 6
    # One obs broadcast against a grid of goals (the +Value ablation's use).
    assert networks.actor_input(env, obs, jnp.zeros((4, 5, 2))).shape == (4, 5, 6)


def test_relative_goal_input_is_the_normalised_offset_from_phi():
    env = StubEnv()
    obs = jnp.arange(3.0)  # phi = obs[1:3] = (1, 2)
    goal = jnp.array([5.0, -10.0])
    feats = networks.actor_input(env, obs, goal, relative_goal=True)
    # obs features as before; goal feature (5 - 1, -10 - 2) / 5 = (0.8, -2.4)
    np.testing.assert_allclose(feats, [0.0, 0.1, 0.2, 0.0, 0.8, -2.4], rtol=1e-6)
    # the same offset from another position gives the same goal feature
    moved = networks.actor_input(env, obs + 3.0, goal + 3.0, relative_goal=True)
    np.testing.assert_allclose(moved[4:], feats[4:], rtol=1e-6)
    assert networks.make_networks(SACConfig(relative_goal=True), env).relative_goal
    assert not networks.make_networks(SACConfig(), env).relative_goal


def test_twin_critic_params_are_stacked_and_distinct(nets):
    params = nets.critic.init(jax.random.key(0), jnp.zeros((1, 6)), jnp.zeros((1, 2)))
    for leaf in jax.tree.leaves(params):
        assert leaf.shape[0] == networks.N_CRITICS
    kernel = params["params"]["members"]["MLP_0"]["Dense_0"]["kernel"]
    chex.assert_shape(kernel, (2, 8, 32))  # (member, feat + action, hidden)
    assert not np.allclose(kernel[0], kernel[1])
    q = nets.critic.apply(params, jnp.ones((5, 6)), jnp.ones((5, 2)))
    chex.assert_shape(q, (2, 5))
    assert not np.allclose(q[0], q[1])


def _critic_by_hand(member_params: dict, x: np.ndarray, n_hidden: int) -> np.ndarray:
    """One critic member's Q for inputs x (B, f): Dense -> LayerNorm (biased variance,
    flax's eps 1e-6) -> ReLU per hidden layer, then the linear output, in float64."""
    h = x.astype(np.float64)
    for i in range(n_hidden):
        dense, norm = member_params[f"Dense_{i}"], member_params[f"LayerNorm_{i}"]
        h = h @ np.asarray(dense["kernel"], np.float64) + np.asarray(dense["bias"])
        h = (h - h.mean(-1, keepdims=True)) / np.sqrt(h.var(-1, keepdims=True) + 1e-6)
        h = np.maximum(h * np.asarray(norm["scale"]) + np.asarray(norm["bias"]), 0.0)
    out = member_params[f"Dense_{n_hidden}"]
    return (h @ np.asarray(out["kernel"], np.float64) + np.asarray(out["bias"]))[:, 0]


def test_critic_layer_norm_matches_a_hand_computed_forward_pass():
    cfg = SACConfig(hidden_sizes=(32, 16), critic_layer_norm=True)
    critic = networks.make_networks(cfg, StubEnv()).critic
    params = critic.init(jax.random.key(1), jnp.zeros((1, 6)), jnp.zeros((1, 2)))
    # Non-trivial LayerNorm scales and offsets, so that both enter the check.
    params = jax.tree_util.tree_map_with_path(
        lambda path, leaf: leaf * 1.7 - 0.3 if "LayerNorm" in jax.tree_util.keystr(path) else leaf,
        params,
    )
    feats = 3.0 * jax.random.normal(jax.random.key(2), (7, 6))
    action = jax.random.uniform(jax.random.key(3), (7, 2), minval=-1.0, maxval=1.0)
    q = critic.apply(params, feats, action)
    chex.assert_shape(q, (2, 7))
    x = np.concatenate([np.asarray(feats), np.asarray(action)], axis=-1)
    members = params["params"]["members"]["MLP_0"]
    for m in range(networks.N_CRITICS):
        member = jax.tree.map(lambda leaf, m=m: leaf[m], members)
        np.testing.assert_allclose(q[m], _critic_by_hand(member, x, 2), rtol=2e-4, atol=2e-4)
    # Off (the paper's SAC), the critic has no LayerNorm parameters at all.
    plain = networks.make_networks(SACConfig(hidden_sizes=(32, 16)), StubEnv()).critic
    plain_params = plain.init(jax.random.key(1), jnp.zeros((1, 6)), jnp.zeros((1, 2)))
    assert "LayerNorm" not in str(jax.tree_util.tree_structure(plain_params))


def test_bounded_critic_is_the_sigmoid_of_the_linear_critic_scaled_to_the_return_range():
    cfg = SACConfig(hidden_sizes=(32, 16), gamma=0.99)
    linear = networks.make_networks(cfg, StubEnv()).critic
    bounded = networks.make_networks(
        dataclasses.replace(cfg, bounded_critic=True), StubEnv()
    ).critic
    params = linear.init(jax.random.key(1), jnp.zeros((1, 6)), jnp.zeros((1, 2)))
    # The same parameters: the option adds none.
    bounded_params = bounded.init(jax.random.key(1), jnp.zeros((1, 6)), jnp.zeros((1, 2)))
    assert jax.tree.structure(params) == jax.tree.structure(bounded_params)
    feats = 30.0 * jax.random.normal(jax.random.key(2), (64, 6))  # far outside the data
    action = jax.random.uniform(jax.random.key(3), (64, 2), minval=-1.0, maxval=1.0)
    raw = np.asarray(linear.apply(params, feats, action), np.float64)
    q = np.asarray(bounded.apply(params, feats, action), np.float64)
    np.testing.assert_allclose(q, 100.0 / (1.0 + np.exp(-raw)), rtol=1e-4, atol=1e-4)
    assert (raw < 0).any() and (q >= 0).all() and (q <= 100.0).all()


def _actor_with_raw_log_std(nets, raw: float):
    """Actor params whose raw log-std output is the constant `raw` (last layer zeroed)."""
    params = nets.actor.init(jax.random.key(0), jnp.zeros((1, 6)))
    last = params["params"]["MLP_0"]["Dense_2"]
    last = {"kernel": jnp.zeros_like(last["kernel"]), "bias": jnp.full_like(last["bias"], raw)}
    return {"params": {"MLP_0": {**params["params"]["MLP_0"], "Dense_2": last}}}


@pytest.mark.parametrize("raw", [-50.0, -3.0, 0.0, 3.0, 50.0])
def test_log_std_is_smoothly_squashed_into_range(nets, raw):
    params = _actor_with_raw_log_std(nets, raw)
    _, log_std = nets.actor.apply(params, jnp.ones((1, 6)))
    expected = -10.0 + 6.0 * (math.tanh(raw) + 1.0)  # SPEC §4
    np.testing.assert_allclose(log_std, expected, atol=1e-5)
    assert np.all((log_std >= -10.0) & (log_std <= 2.0))


def test_log_std_keeps_a_gradient_beyond_where_a_clip_would_stop(nets):
    """A hard clip at raw = 3 would give zero gradient; the tanh squash does not."""
    params = _actor_with_raw_log_std(nets, 3.0)

    def mean_log_std(p):
        return nets.actor.apply(p, jnp.ones((1, 6)))[1].mean()

    grad_bias = jax.grad(mean_log_std)(params)["params"]["MLP_0"]["Dense_2"]["bias"]
    assert np.all(grad_bias[2:] > 1e-4)  # the log-std half of the output layer


def test_log1m_tanh_sq_is_exact_and_keeps_its_gradient():
    u = np.linspace(-8.0, 8.0, 33)
    reference = np.log1p(-(np.tanh(u.astype(np.float64)) ** 2))
    np.testing.assert_allclose(networks.log1m_tanh_sq(jnp.asarray(u)), reference, atol=1e-5)
    # At u = 20 float32 tanh is exactly 1: the naive log(1 - a^2 + 1e-6) is flat there.
    assert float(jnp.tanh(jnp.float32(20.0))) == 1.0
    naive_grad = jax.grad(lambda x: jnp.log(1.0 - jnp.tanh(x) ** 2 + 1e-6))(20.0)
    stable_grad = jax.grad(networks.log1m_tanh_sq)(20.0)
    assert float(naive_grad) == 0.0
    np.testing.assert_allclose(stable_grad, -2.0, rtol=1e-6)  # d/du = -2 tanh(u)
    assert np.isfinite(networks.log1m_tanh_sq(jnp.float32(100.0)))


def test_squashed_gaussian_log_prob_is_the_change_of_variables():
    mean = jnp.array([[0.3, -1.0], [2.0, 0.0]])
    log_std = jnp.array([[-0.5, 0.2], [0.0, -2.0]])
    action, log_prob = networks.squashed_gaussian_sample(mean, log_std, jax.random.key(3))
    a = np.asarray(action, np.float64)
    u = np.arctanh(a)
    std = np.exp(np.asarray(log_std, np.float64))
    gauss = -0.5 * ((u - np.asarray(mean)) / std) ** 2 - np.log(std) - 0.5 * np.log(2 * np.pi)
    expected = np.sum(gauss - np.log(1.0 - a**2), axis=-1)
    np.testing.assert_allclose(log_prob, expected, rtol=1e-3, atol=1e-3)
    assert np.all(np.abs(a) < 1.0)


def test_squashed_density_integrates_to_one():
    """1-D: integrate exp(log pi(a)) over (-1, 1) using the same formula as the sampler."""
    mean, log_std = 0.7, -0.3
    a = np.linspace(-1 + 1e-6, 1 - 1e-6, 200_001)
    u = np.arctanh(a)
    std = math.exp(log_std)
    log_n = -0.5 * ((u - mean) / std) ** 2 - log_std - 0.5 * math.log(2 * math.pi)
    log_pi = log_n - np.asarray(networks.log1m_tanh_sq(jnp.asarray(u)), np.float64)
    assert abs(np.trapezoid(np.exp(log_pi), a) - 1.0) < 1e-3


def test_select_action(nets):
    params = nets.actor.init(jax.random.key(1), jnp.zeros((1, 6)))
    feats = jax.random.normal(jax.random.key(2), (7, 6)) * 3
    mean, _ = nets.actor.apply(params, feats)
    det = networks.select_action(nets, params, feats, None, deterministic=True)
    np.testing.assert_allclose(det, jnp.tanh(mean), rtol=1e-6)
    sto = networks.select_action(nets, params, feats, jax.random.key(4))
    chex.assert_shape(sto, (7, 2))
    assert np.all(np.abs(sto) < 1.0) and not np.allclose(sto, det)
