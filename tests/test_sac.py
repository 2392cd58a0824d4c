"""SAC: analytic probe environments, the update schedule, shapes and determinism.

Probe settings (small nets, lr 1e-3 for speed, gamma 0.8, alpha fixed at 1e-6 ~ 0 so the
entropy term vanishes from the expected values) are test-only; the losses are the
library's. The three probes share one compiled program (their parameters are traced).
"""

import dataclasses
import functools
from typing import NamedTuple

import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from d2c_jax.config import SACConfig
from d2c_jax.core import networks, optim, sac, types


class ProbeEnv:
    """obs (1,), goal (1,), action (1,); identity normalisation."""

    obs_dim, action_dim, goal_dim = 1, 1, 1

    def normalize_obs(self, obs):
        return obs

    def normalize_goal(self, goal):
        return goal


class SmallEnv:
    """obs (3,) -> features (3,), goal (2,), action (2,)."""

    obs_dim, action_dim, goal_dim = 3, 2, 2

    def normalize_obs(self, obs):
        return obs / 2.0

    def normalize_goal(self, goal):
        return goal / 4.0

    def goal_of_obs(self, obs):
        return obs[..., :2]


# gamma 0.8: far from 1, so Q(s0) = gamma is distinguishable from Q(s1) = 1.
PROBE_CFG = SACConfig(
    hidden_sizes=(64, 64), batch_size=64, actor_lr=1e-3, critic_lr=1e-3,
    init_alpha=1e-6, learn_alpha=False, gamma=0.8,
)  # fmt: skip
CFG = SACConfig(hidden_sizes=(32, 32), batch_size=16)


def random_batch(env, batch_size, key) -> types.Batch:
    ks = jax.random.split(key, 5)
    b = batch_size
    return types.Batch(
        obs=jax.random.normal(ks[0], (b, env.obs_dim)),
        action=jax.random.uniform(ks[1], (b, env.action_dim), minval=-1, maxval=1),
        reward=jax.random.bernoulli(ks[2], 0.3, (b,)).astype(jnp.float32),
        next_obs=jax.random.normal(ks[3], (b, env.obs_dim)),
        goal=jax.random.normal(ks[4], (b, env.goal_dim)),
        mask=jnp.ones((b,)),
    )


class Probe(NamedTuple):
    """Two states s0 = 0 and s1 = 1 (goal 0); a batch holds a share `first` of s0 -> s1
    transitions (r = 0, bootstrapped) and otherwise s1 -> terminal with the reward
    r(a) = c - k (a - a_star)^2. Actions are uniform in [-1, 1]."""

    first: float
    c: float
    k: float
    a_star: float


PROBE_ACTIONS = jnp.linspace(-1.0, 1.0, 9)


def probe_batch(p: Probe, key) -> types.Batch:
    b = PROBE_CFG.batch_size
    first = jnp.arange(b) < p.first * b
    action = jax.random.uniform(key, (b, 1), minval=-1, maxval=1)
    obs = jnp.where(first, 0.0, 1.0)[:, None]
    reward = jnp.where(first, 0.0, p.c - p.k * (action[:, 0] - p.a_star) ** 2)
    return types.Batch(obs, action, reward, obs + 1.0, jnp.zeros((b, 1)), first.astype(jnp.float32))


def parts(cfg: SACConfig, env):
    """(nets, optimisers, hyperparameters) of `cfg`, as the trainer builds them."""
    return networks.make_networks(cfg, env), sac.make_optimizers(), sac.hyperparams(cfg)


class OffOriginProbeEnv(ProbeEnv):
    """ProbeEnv with its features shifted by 0.5, so that s0 with a = 0 is not an all-zero
    network input (see `test_probe_two_steps_with_critic_layer_norm`)."""

    def normalize_obs(self, obs):
        return obs + 0.5


PROBE_ENV, OFF_ORIGIN_PROBE_ENV = ProbeEnv(), OffOriginProbeEnv()


@functools.partial(jax.jit, static_argnums=(2, 3))
def run_probe(p: Probe, key, cfg: SACConfig = PROBE_CFG, env: ProbeEnv = PROBE_ENV):
    """init + 3000 updates (in blocks) of `cfg` on `env`; returns Q (2 critics, s0/s1, 9
    actions) and tanh(mean) at s0/s1."""
    nets, opt, hp = parts(cfg, env)
    n = sac.block_size(cfg)

    def body(s, k):
        k_batch, k_update = jax.random.split(k)
        batches = jax.vmap(lambda kb: probe_batch(p, kb))(jax.random.split(k_batch, n))
        return sac.update_sac_block(cfg, nets, opt, hp, s, batches, env, k_update)

    k_init, k_run = jax.random.split(key)
    state = sac.init_sac(nets, opt, env, hp, k_init)
    state, metrics = jax.lax.scan(body, state, jax.random.split(k_run, 3000 // n))
    obs = jnp.repeat(jnp.array([0.0, 1.0]), 9)[:, None]
    feats = networks.actor_input(env, obs, jnp.zeros((18, 1)))
    q = nets.critic.apply(state.critic_params, feats, jnp.tile(PROBE_ACTIONS, 2)[:, None])
    policy = sac.make_policy(nets, state, env, deterministic=True)
    best = jax.vmap(lambda o: policy(o, jnp.zeros(1), None))(jnp.array([[0.0], [1.0]]))
    return q.reshape(2, 2, 9), best[:, 0], metrics["sac/alpha"]


def probe(p: Probe, cfg: SACConfig = PROBE_CFG, env: ProbeEnv = PROBE_ENV):
    """Runs a probe (all of one `cfg` and `env` share one compiled program); alpha must
    stay fixed at ~0."""
    q, best, alpha = run_probe(p, jax.random.key(0), cfg, env)
    np.testing.assert_allclose(alpha, PROBE_CFG.init_alpha, rtol=1e-5)
    return np.asarray(q), np.asarray(best)


# --- probe environments -----------------------------------------------------------------


def test_probe_one_step_terminal_reward_one():
    q, _ = probe(Probe(first=0.0, c=1.0, k=0.0, a_star=0.0))
    np.testing.assert_allclose(q[:, 1], 1.0, atol=0.05)  # Q(s1, a) = 1 for every a


def test_probe_two_steps_reward_at_the_end():
    """s0 -> s1 (r = 0), s1 -> terminal (r = 1): Q(s1) = 1, Q(s0) = gamma (0.8 here)."""
    q, _ = probe(Probe(first=0.5, c=1.0, k=0.0, a_star=0.0))
    np.testing.assert_allclose(q[:, 1], 1.0, atol=0.05)
    np.testing.assert_allclose(q[:, 0], PROBE_CFG.gamma, atol=0.05)


def test_probe_action_dependent_reward_actor_picks_best_action():
    """One step, r = 1 - (a - 0.3)^2, terminal: Q(s1, a) is that parabola, the actor -> 0.3."""
    q, best = probe(Probe(first=0.0, c=1.0, k=1.0, a_star=0.3))
    np.testing.assert_allclose(best[1], 0.3, atol=0.1)
    parabola = np.broadcast_to(1.0 - (PROBE_ACTIONS - 0.3) ** 2, q[:, 1].shape)
    np.testing.assert_allclose(q[:, 1], parabola, atol=0.05)


def test_probe_two_steps_with_critic_layer_norm():
    """The same two-step values with LayerNorm in the critics (`critic_layer_norm`).

    On the plain probe the LayerNorm critic misses Q(s0, a = 0) by 0.1 (0.70): there the
    network's input is all zeros, the first layer's pre-activation is its bias alone, and
    LayerNorm, which is invariant to the scale of its input, jumps between that and the
    direction of W x for small x. The envs' features are all zero rarely or never (cos θ on
    the mazes, a unit quaternion on the Ant), so the probe is run with its features
    shifted off the origin."""
    cfg = dataclasses.replace(PROBE_CFG, critic_layer_norm=True)
    q, _ = probe(Probe(first=0.5, c=1.0, k=0.0, a_star=0.0), cfg, OFF_ORIGIN_PROBE_ENV)
    np.testing.assert_allclose(q[:, 1], 1.0, atol=0.05)
    np.testing.assert_allclose(q[:, 0], cfg.gamma, atol=0.05)


def test_probe_two_steps_with_bounded_critic():
    """The same two-step values with the sigmoid-bounded critic (`bounded_critic`): Q(s1) =
    1 and Q(s0) = gamma, inside its range (0, 1/(1 - gamma)) = (0, 5) here."""
    cfg = dataclasses.replace(PROBE_CFG, bounded_critic=True)
    q, _ = probe(Probe(first=0.5, c=1.0, k=0.0, a_star=0.0), cfg)
    np.testing.assert_allclose(q[:, 1], 1.0, atol=0.05)
    np.testing.assert_allclose(q[:, 0], cfg.gamma, atol=0.05)


# --- losses -----------------------------------------------------------------------------


def test_actor_mean_reg_holds_the_mean_where_its_pull_balances_the_critics():
    """r = 1 - (a - 1)^2 at s1, terminal: the best action is a -> 1, so plain SAC drives the
    pre-tanh mean u on toward infinity (tanh u -> 1). With lambda ||u||^2 added to J_pi the
    actor stops where dQ/du = 2 (1 - tanh u)(1 - tanh^2 u) equals 2 lambda u."""
    from scipy.optimize import brentq

    reg = 0.1
    u_star = brentq(lambda u: (1 - np.tanh(u)) * (1 - np.tanh(u) ** 2) - reg * u, 0.0, 5.0)
    edge = Probe(first=0.0, c=1.0, k=1.0, a_star=1.0)
    _, plain = probe(edge)
    _, held = probe(edge, dataclasses.replace(PROBE_CFG, actor_mean_reg=reg))
    assert plain[1] > 0.95
    np.testing.assert_allclose(held[1], np.tanh(u_star), atol=0.05)  # 0.76


def test_actor_mean_reg_adds_lambda_times_the_squared_pre_tanh_mean(small):
    feats = networks.actor_input(small.env, small.batches[0].obs, small.batches[0].goal)
    args = (small.state.actor_params, small.nets, small.state.critic_params, 0.3, feats)
    key = jax.random.key(4)
    plain, logp = sac.actor_loss(*args, key)
    held, logp_held = sac.actor_loss(*args, key, 0.25)
    mean, _ = small.nets.actor.apply(small.state.actor_params, feats)
    np.testing.assert_allclose(held - plain, 0.25 * np.mean(np.sum(mean**2, -1)), rtol=1e-5)
    np.testing.assert_array_equal(logp, logp_held)


def test_soft_td_target_and_critic_loss_by_hand():
    env = SmallEnv()
    nets, opt, hp = parts(CFG, env)
    batch = random_batch(env, 8, jax.random.key(1))._replace(mask=jnp.arange(8) % 2)

    @jax.jit
    def both(key):
        state = sac.init_sac(nets, opt, env, hp, jax.random.key(0))
        feats = networks.actor_input(env, batch.obs, batch.goal)
        next_feats = networks.actor_input(env, batch.next_obs, batch.goal)
        y, logp = sac.soft_td_target(
            nets, state.actor_params, state.target_critic_params, 0.3, next_feats,
            batch.reward, batch.mask, 0.9, key,
        )  # fmt: skip
        # By hand: the same sample, min over the twins, mask, entropy bonus.
        mean, log_std = nets.actor.apply(state.actor_params, next_feats)
        a_next, logp_ref = networks.squashed_gaussian_sample(mean, log_std, key)
        q_next = nets.critic.apply(state.target_critic_params, next_feats, a_next)
        v_next = jnp.minimum(q_next[0], q_next[1]) - 0.3 * logp_ref
        y_ref = batch.reward + 0.9 * batch.mask * v_next
        loss, q = sac.critic_loss(state.critic_params, nets, feats, batch.action, y)
        loss_ref = 0.5 * ((q - y) ** 2).mean(-1).sum()
        alpha_grad = jax.grad(sac.alpha_loss)(jnp.log(0.3), logp, -2.0)
        return y, y_ref, loss, loss_ref, alpha_grad, -(logp - 2.0).mean()

    y, y_ref, loss, loss_ref, alpha_grad, alpha_grad_ref = both(jax.random.key(2))
    np.testing.assert_allclose(y, y_ref, rtol=1e-5, atol=1e-6)
    np.testing.assert_array_equal(y[::2], batch.reward[::2])  # mask 0: no bootstrap
    np.testing.assert_allclose(loss, loss_ref, rtol=1e-6)
    np.testing.assert_allclose(alpha_grad, alpha_grad_ref, rtol=1e-5)


# --- one update -------------------------------------------------------------------------


class Small(NamedTuple):
    env: SmallEnv
    nets: networks.SACNetworks
    opt: sac.Optimizers
    hp: sac.SACHyperparams
    state: sac.SACState
    block: object  # jitted (state, batches (2, B, ...), key) -> (state, metrics)
    batches: list  # 6 batches, three blocks' worth


@pytest.fixture(scope="module")
def small():
    env = SmallEnv()
    nets, opt, hp = parts(CFG, env)
    state = jax.jit(lambda k: sac.init_sac(nets, opt, env, hp, k))(jax.random.key(0))
    block = jax.jit(lambda s, b, k: sac.update_sac_block(CFG, nets, opt, hp, s, b, env, k))
    batches = [random_batch(env, CFG.batch_size, jax.random.key(10 + i)) for i in range(6)]
    return Small(env, nets, opt, hp, state, block, batches)


def stack(*batches):
    return jax.tree.map(lambda *xs: jnp.stack(xs), *batches)


def test_init_sac(small):
    for leaf in jax.tree.leaves(small.state.critic_params):
        assert leaf.shape[0] == 2
    chex.assert_trees_all_equal(small.state.critic_params, small.state.target_critic_params)
    np.testing.assert_allclose(jnp.exp(small.state.log_alpha), 0.3, rtol=1e-6)
    assert int(small.state.step) == 0
    assert sac.target_entropy(CFG, small.env.action_dim) == -2.0


def test_adam_step_with_a_traced_learning_rate_is_optax_adam_bitwise():
    """The optimisers are Adam without its step size, which the update applies from the
    hyperparameter pytree: the same bits as optax.adam(lr) with lr compiled in."""
    import optax

    params = {"w": jax.random.normal(jax.random.key(0), (5, 3))}
    grads = [jax.tree.map(lambda x, i=i: jnp.sin(x * (i + 1)), params) for i in range(3)]
    lr = 3e-4
    reference, ref_state = params, optax.adam(lr).init(params)
    ours, our_state = params, sac.make_optimizers().actor.init(params)
    for g in grads:
        updates, ref_state = optax.adam(lr).update(g, ref_state, reference)
        reference = optax.apply_updates(reference, updates)
        ours, our_state = jax.jit(optim.adam_step, static_argnums=0)(
            sac.make_optimizers().actor, jnp.float32(lr), g, our_state, ours
        )
    np.testing.assert_array_equal(ours["w"], reference["w"])


def test_block_is_critic_then_critic_actor_alpha_and_target_by_hand(small):
    """Block of 2 (actor and target every 2 updates): update 1 moves only the critic;
    update 2 the critic, then the actor and alpha, then the Polyak target (tau = 0.01)."""
    env, nets, opt, hp, s0 = small.env, small.nets, small.opt, small.hp, small.state
    b0, b1 = small.batches[:2]
    key = jax.random.key(1)
    blk, metrics = small.block(s0, stack(b0, b1), key)
    assert int(blk.step) == 2
    assert all(np.shape(v) == () and np.isfinite(v) for v in metrics.values())
    expected = {"sac/critic_loss", "sac/actor_loss", "sac/alpha", "sac/q_mean", "sac/entropy"}
    assert expected <= set(metrics)

    @jax.jit
    def by_hand(state):
        k0, k1 = jax.random.split(key, 2)  # the block's key per update
        k0_critic, _ = jax.random.split(k0)
        k1_critic, k1_actor = jax.random.split(k1)
        f0, n0 = sac._features(nets, env, b0)
        first, _ = sac._critic_step(CFG, nets, opt, hp, state, f0, n0, b0, k0_critic)
        f1, n1 = sac._features(nets, env, b1)
        second, _ = sac._critic_step(CFG, nets, opt, hp, first, f1, n1, b1, k1_critic)
        second = sac._actor_step(CFG, nets, opt, hp, second, f1, env.action_dim, k1_actor)
        return first, sac._polyak(second, hp.tau)

    first, second = by_hand(s0)
    chex.assert_trees_all_equal(first.actor_params, s0.actor_params)
    chex.assert_trees_all_equal(first.target_critic_params, s0.target_critic_params)
    assert float(first.log_alpha) == float(s0.log_alpha)
    assert not np.allclose(*[jax.tree.leaves(p.critic_params)[0] for p in (s0, first)])
    assert float(second.log_alpha) != float(first.log_alpha)
    chex.assert_trees_all_close(
        (blk.actor_params, blk.critic_params, blk.log_alpha, blk.target_critic_params),
        (second.actor_params, second.critic_params, second.log_alpha, second.target_critic_params),
        rtol=1e-5,
        atol=1e-7,
    )
    tgt = jax.tree.map(lambda t, c: 0.99 * t + 0.01 * c, s0.target_critic_params, blk.critic_params)
    chex.assert_trees_all_close(blk.target_critic_params, tgt, rtol=1e-5, atol=1e-7)


def test_learning_rates_and_tau_are_read_from_the_hyperparameters(small):
    """A sweep changes the pytree, not the program: lr 0 freezes the nets, tau 0 the target."""
    zero = small.hp.replace(actor_lr=jnp.float32(0), critic_lr=jnp.float32(0), tau=jnp.float32(0))
    nets, opt, env = small.nets, small.opt, small.env
    block = jax.jit(lambda hp, s, b, k: sac.update_sac_block(CFG, nets, opt, hp, s, b, env, k))
    batches, key = stack(*small.batches[:2]), jax.random.key(4)
    frozen, _ = block(zero, small.state, batches, key)
    chex.assert_trees_all_equal(frozen.critic_params, small.state.critic_params)
    chex.assert_trees_all_equal(frozen.actor_params, small.state.actor_params)
    chex.assert_trees_all_equal(frozen.target_critic_params, small.state.target_critic_params)
    moved, _ = block(small.hp, small.state, batches, key)
    assert not np.allclose(*[jax.tree.leaves(p.critic_params)[0] for p in (moved, frozen)])


def _three_blocks(small, key):
    state = small.state
    for i in range(3):
        batches = stack(*small.batches[2 * i : 2 * i + 2])
        state, _ = small.block(state, batches, jax.random.fold_in(key, i))
    return state


def test_same_key_same_parameters_different_key_different(small):
    a = _three_blocks(small, jax.random.key(5))
    b = _three_blocks(small, jax.random.key(5))
    c = _three_blocks(small, jax.random.key(6))
    chex.assert_trees_all_equal(a, b)
    assert not np.allclose(jax.tree.leaves(a.actor_params)[0], jax.tree.leaves(c.actor_params)[0])


def test_block_vmaps_over_seeds(small):
    """The trainer vmaps blocks over seeds: results equal the unbatched ones."""
    s0 = small.state
    s1, _ = small.block(s0, stack(*small.batches[:2]), jax.random.key(7))  # another "seed"
    seeds = jax.tree.map(lambda a, b: jnp.stack([a, b]), s0, s1)
    batches = stack(*small.batches[2:4])
    both = jax.tree.map(lambda x: jnp.stack([x, x]), batches)
    nets, opt, hp, env = small.nets, small.opt, small.hp, small.env
    vblock = jax.jit(
        jax.vmap(lambda s, b, k: sac.update_sac_block(CFG, nets, opt, hp, s, b, env, k))
    )
    keys = jnp.stack([jax.random.key(1), jax.random.key(2)])
    out, _ = vblock(seeds, both, keys)
    for i, (state, key) in enumerate(((s0, keys[0]), (s1, keys[1]))):
        alone, _ = small.block(state, batches, key)
        chex.assert_trees_all_close(
            jax.tree.map(lambda x, i=i: x[i], out), alone, rtol=1e-5, atol=1e-6
        )


def test_policy_and_state_value(small):
    env, nets, state = small.env, small.nets, small.state
    policy = sac.make_policy(nets, state, env, deterministic=False)
    a = policy(jnp.ones(3), jnp.zeros(2), jax.random.key(0))
    chex.assert_shape(a, (2,))
    assert np.all(np.abs(a) < 1)
    v = sac.state_value(nets, state, env, jnp.ones(3), jnp.zeros((4, 5, 2)))
    chex.assert_shape(v, (4, 5))
    feats = networks.actor_input(env, jnp.ones(3), jnp.zeros(2))
    det = networks.select_action(nets, state.actor_params, feats, None, deterministic=True)
    q = nets.critic.apply(state.critic_params, feats, det)
    np.testing.assert_allclose(v[0, 0], q.min(), rtol=1e-5)


def test_relative_goal_acts_and_learns_as_the_absolute_nets_on_the_offset(small):
    """`relative_goal`: on transitions whose phi does not move (phi(s') = phi(s)), the
    update with goal g equals the absolute update with goal g - phi(s) (SmallEnv's goal
    normalisation is linear), and so does the policy; the plain nets differ."""
    env, s0 = small.env, small.state
    cfg = dataclasses.replace(CFG, relative_goal=True)
    nets, opt, hp = parts(cfg, env)
    batches = stack(*small.batches[:2])
    batches = batches._replace(next_obs=batches.next_obs.at[..., :2].set(batches.obs[..., :2]))
    offset = batches._replace(goal=batches.goal - batches.obs[..., :2])
    key = jax.random.key(3)
    relative, _ = jax.jit(lambda s: sac.update_sac_block(cfg, nets, opt, hp, s, batches, env, key))(
        s0
    )
    absolute, _ = small.block(s0, offset, key)
    chex.assert_trees_all_close(relative, absolute, rtol=1e-4, atol=1e-6)
    plain, _ = small.block(s0, batches, key)
    assert not np.allclose(
        jax.tree.leaves(plain.actor_params)[0], jax.tree.leaves(relative.actor_params)[0]
    )
    obs, goal = jnp.array([1.0, -2.0, 0.5]), jnp.array([3.0, 1.0])
    act = sac.make_policy(nets, relative, env, deterministic=True)(obs, goal, None)
    ref = sac.make_policy(small.nets, relative, env, deterministic=True)(obs, goal - obs[:2], None)
    np.testing.assert_allclose(act, ref, rtol=1e-5)
    v = sac.state_value(nets, relative, env, obs, goal)
    np.testing.assert_allclose(
        v, sac.state_value(small.nets, relative, env, obs, goal - obs[:2]), rtol=1e-5
    )


def test_clipped_targets_stay_in_the_return_range(small):
    """clip_to_return_range by hand, and `clip_target` in the update: a target critic
    whose outputs are far beyond 1 / (1 - gamma) gives targets in [0, 1 / (1 - gamma)]
    only with the clip on."""
    np.testing.assert_allclose(
        sac.clip_to_return_range(jnp.array([-5.0, 50.0, 500.0]), 0.99), [0.0, 50.0, 100.0]
    )
    # Every bias of the target critic + 1e3: its Q values are thousands (of either sign).
    inflated = small.state.replace(
        target_critic_params=jax.tree.map(lambda x: x + 1e3, small.state.target_critic_params)
    )
    batches = stack(*small.batches[:2])
    bound = 1.0 / (1.0 - CFG.gamma)
    for clip in (False, True):
        cfg = dataclasses.replace(CFG, clip_target=clip)
        _, metrics = jax.jit(
            lambda s, b, k, cfg=cfg: sac.update_sac_block(
                cfg, small.nets, small.opt, small.hp, s, b, small.env, k
            )
        )(inflated, batches, jax.random.key(3))
        target = float(metrics["sac/target_mean"])
        assert (0.0 <= target <= bound * (1 + 1e-6)) if clip else abs(target) > bound, target


def test_soft_return_floor_by_hand_and_the_share_of_targets_below_it(small):
    """soft_return_floor by hand, and "sac/target_below_floor": a target critic whose
    output layer is the constant b gives targets r + gamma (b - alpha log pi), all below
    the floor for b = -1000 and none for b = 50, read before `clip_target` lifts them."""
    # Q = gamma (Q + alpha H*): 0.99 * 0.01 * -8 / 0.01 = -7.92; alpha 0 gives 0.
    np.testing.assert_allclose(sac.soft_return_floor(0.01, -8.0, 0.99), -7.92, rtol=1e-6)
    assert sac.soft_return_floor(0.0, -8.0, 0.99) == 0.0
    batches = stack(*small.batches[:2])

    def constant_target(b):
        params = small.state.target_critic_params
        out = params["params"]["members"]["MLP_0"]["Dense_2"]
        out = {"bias": jnp.full_like(out["bias"], b), "kernel": jnp.zeros_like(out["kernel"])}
        mlp = {**params["params"]["members"]["MLP_0"], "Dense_2": out}
        return small.state.replace(target_critic_params={"params": {"members": {"MLP_0": mlp}}})

    for b, share in ((-1000.0, 1.0), (50.0, 0.0)):
        for clip in (False, True):
            cfg = dataclasses.replace(CFG, clip_target=clip)
            _, metrics = jax.jit(
                lambda s, bt, k, cfg=cfg: sac.update_sac_block(
                    cfg, small.nets, small.opt, small.hp, s, bt, small.env, k
                )
            )(constant_target(b), batches, jax.random.key(4))
            assert float(metrics["sac/target_below_floor"]) == share, (b, clip, metrics)
