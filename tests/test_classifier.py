"""Tests of the classifier ensemble and Eq. 5 (d2c_jax/classifier.py)."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

from d2c_jax.config import ClassifierConfig
from d2c_jax.curricula import classifier as clf
from envs.base import GoalEnv


class BoxEnv:
    """Just the goal interface of a GoalEnv, on a box (no physics)."""

    clip_goal = GoalEnv.clip_goal
    sample_uniform_goals = GoalEnv.sample_uniform_goals

    def __init__(self, low, high, mask=None):
        self.goal_low = np.asarray(low, np.float32)
        self.goal_high = np.asarray(high, np.float32)
        self.goal_dim = self.goal_low.shape[0]
        ones = np.ones(self.goal_dim, np.float32)
        self.goal_noise_mask = ones if mask is None else np.asarray(mask, np.float32)


UNIT = BoxEnv([-1.0, -1.0], [1.0, 1.0])


OPT = clf.make_optimizer()


def _init(net, seed=0):
    """Jitted `init_classifier` (one compile instead of many eager ops)."""
    return jax.jit(clf.init_classifier, static_argnums=(0, 1, 2))(net, OPT, 2, jax.random.key(seed))


# --- the MI estimator ----------------------------------------------------------------


def test_mi_identical_confident_heads_is_log2():
    p = jnp.array([1.0, 0.0, 1.0, 0.0])
    assert float(clf.mutual_information(p, p)) == pytest.approx(math.log(2.0), abs=1e-4)
    # A head that copies the other's complement is just as informative.
    assert float(clf.mutual_information(p, 1.0 - p)) == pytest.approx(math.log(2.0), abs=1e-4)


def test_mi_independent_heads_is_zero():
    p_i = jnp.array([1.0, 1.0, 0.0, 0.0])
    p_j = jnp.array([1.0, 0.0, 1.0, 0.0])
    assert abs(float(clf.mutual_information(p_i, p_j))) < 1e-5
    # A constant head carries no information about the other.
    assert abs(float(clf.mutual_information(p_i, jnp.full(4, 0.3)))) < 1e-6


def test_mi_hand_computed_tiny_batch():
    # p_i = (0.9, 0.3), p_j = (0.6, 0.2): joint P(1,1) = (0.54 + 0.06)/2 = 0.3,
    # P(1,0) = (0.36 + 0.24)/2 = 0.3, P(0,1) = (0.06 + 0.14)/2 = 0.1,
    # P(0,0) = (0.04 + 0.56)/2 = 0.3; marginals P_i = (0.6, 0.4), P_j = (0.4, 0.6).
    expected = (
        0.3 * math.log(0.3 / (0.6 * 0.4))
        + 0.3 * math.log(0.3 / (0.6 * 0.6))
        + 0.1 * math.log(0.1 / (0.4 * 0.4))
        + 0.3 * math.log(0.3 / (0.4 * 0.6))
    )  # = 0.0321...
    got = clf.mutual_information(jnp.array([0.9, 0.3]), jnp.array([0.6, 0.2]))
    assert float(got) == pytest.approx(expected, rel=1e-5)
    assert expected == pytest.approx(0.03219, abs=1e-5)


def test_mean_pairwise_mi_averages_pairs():
    a = jnp.array([1.0, 0.0, 1.0, 0.0])
    b = jnp.array([1.0, 1.0, 0.0, 0.0])
    probs = jnp.stack([a, a, b], axis=-1)  # pairs: (a,a)=log2, (a,b)=0, (a,b)=0
    assert float(clf.mean_pairwise_mi(probs)) == pytest.approx(math.log(2.0) / 3, abs=1e-4)
    assert float(clf.mean_pairwise_mi(probs[:, :1])) == 0.0


# --- the network ---------------------------------------------------------------------


def _net(low, high, n_heads=2, hidden=(16, 16)):
    return clf.Classifier(
        n_heads=n_heads, hidden_sizes=hidden, goal_low=tuple(low), goal_high=tuple(high)
    )


def test_marginal_kl_hand_computed():
    probs = jnp.asarray([[0.4, 0.8], [0.6, 1.0]], jnp.float32)  # head means 0.5 and 0.9
    # Head 0 sits on the prior; the mean over the two heads.
    want = (0.9 * np.log(0.9 / 0.5) + 0.1 * np.log(0.1 / 0.5)) / 2
    assert float(clf.marginal_kl(probs, 0.5)) == pytest.approx(want, rel=1e-5)
    kl_02 = [m * np.log(m / 0.2) + (1 - m) * np.log((1 - m) / 0.8) for m in (0.5, 0.9)]
    assert float(clf.marginal_kl(probs, 0.2)) == pytest.approx(np.mean(kl_02), rel=1e-5)


def test_marginal_kl_per_goal_groups():
    """group = 2: rows (0, 1) and (2, 3) each share a goal; the KL is taken per group."""
    probs = jnp.asarray([[0.1], [0.3], [0.7], [0.9]], jnp.float32)  # group means 0.2, 0.8
    pooled = float(clf.marginal_kl(probs, 0.5))  # pooled mean 0.5 sits on the prior
    assert pooled == pytest.approx(0.0, abs=1e-6)
    kl = 0.2 * np.log(0.2 / 0.5) + 0.8 * np.log(0.8 / 0.5)  # both groups, by symmetry
    assert float(clf.marginal_kl(probs, 0.5, group=2)) == pytest.approx(kl, rel=1e-5)
    goals = jnp.arange(10.0)[:, None]
    np.testing.assert_array_equal(clf.grouped_goals(goals, 4)[:, 0], [0, 0, 0, 0, 1, 1, 1, 1, 2, 2])
    assert clf.grouped_goals(goals, 1) is goals


def test_classifier_normalises_inputs_with_goal_bounds():
    big, unit = _net((-18.0, -2.0), (18.0, 6.0)), _net((-1.0, -1.0), (1.0, 1.0))
    params = big.init(jax.random.key(0), jnp.zeros((1, 2)), jnp.zeros((1, 2)))
    raw = np.random.default_rng(0).uniform(-1.0, 1.0, (5, 2, 2)).astype(np.float32)
    half, centre = np.array([18.0, 4.0]), np.array([0.0, 2.0])
    x, g = raw[:, 0] * half + centre, raw[:, 1] * half + centre
    both = jax.jit(lambda p: (big.apply(p, x, g), unit.apply(p, raw[:, 0], raw[:, 1])))
    np.testing.assert_allclose(*both(params), atol=1e-5)


def test_p_pseudo_is_mean_of_heads_and_broadcasts_goal():
    cfg = ClassifierConfig(n_heads=3, hidden_sizes=(8,))
    net = clf.make_classifier(cfg, UNIT)
    state = _init(net)
    x = np.random.default_rng(1).uniform(-1.0, 1.0, (4, 5, 2)).astype(np.float32)
    g = jnp.array([0.5, -0.5])
    heads, p = jax.jit(lambda q: (jax.nn.sigmoid(net.apply(q, x, g)), clf.p_pseudo(net, q, x, g)))(
        state.params
    )
    assert heads.shape == (4, 5, 3)
    assert p.shape == (4, 5)
    np.testing.assert_allclose(p, heads.mean(-1), atol=1e-6)


def test_reward_fn_equals_p_pseudo_and_stops_gradients():
    cfg = ClassifierConfig(n_heads=2, hidden_sizes=(8,))
    net = clf.make_classifier(cfg, UNIT)
    params = _init(net).params
    ag, g = np.random.default_rng(1).uniform(-1.0, 1.0, (2, 7, 2)).astype(np.float32)
    reward, p = jax.jit(lambda q: (clf.make_reward_fn(net, q)(ag, g), clf.p_pseudo(net, q, ag, g)))(
        params
    )
    np.testing.assert_allclose(reward, p, atol=1e-6)
    grads = jax.jit(jax.grad(lambda q: clf.make_reward_fn(net, q)(ag, g).sum()))(params)
    assert all(float(jnp.abs(leaf).max()) == 0.0 for leaf in jax.tree.leaves(grads))


# --- Eq. 5 ----------------------------------------------------------------------------


def test_loss_matches_hand_written_eq5():
    cfg = ClassifierConfig(n_heads=3, hidden_sizes=(8,), diversity_weight=0.7, marginal_weight=0.3)
    net = clf.make_classifier(cfg, UNIT)
    # Larger weights make the heads confident, so the MI term is far from zero.
    params = jax.tree.map(lambda w: 4.0 * w, _init(net).params)
    rows = np.random.default_rng(1).uniform(-1.0, 1.0, (4, 6, 2)).astype(np.float32)
    batch = clf.ClassifierBatch(*rows, uniform_goals=rows[3])
    hp = clf.hyperparams(cfg)
    total, m = jax.jit(lambda p: clf.loss(cfg, net, hp, p, batch))(params)

    def bce(logits, label):  # -log sigmoid(+-z) in float64, mean over batch, sum over heads
        z = np.asarray(logits, np.float64)
        return float(np.sum(np.mean(np.logaddexp(0.0, -z if label else z), axis=0)))

    logits = jax.jit(lambda p, x: net.apply(p, x, batch.cond_goals))
    neg = bce(logits(params, batch.negatives), 0)
    pos = bce(logits(params, batch.positives), 1)
    pu = np.asarray(jax.nn.sigmoid(logits(params, batch.uniform)), np.float64)

    def mi_np(a, b):  # the SPEC §3 estimator written out in numpy
        joint = np.stack([a, 1 - a], 1).T @ np.stack([b, 1 - b], 1) / len(a)
        outer = joint.sum(1, keepdims=True) * joint.sum(0, keepdims=True)
        return float(np.sum(joint * np.log(joint / outer)))

    mi = np.mean([mi_np(pu[:, i], pu[:, j]) for i, j in [(0, 1), (0, 2), (1, 2)]])
    mean = pu.mean(axis=0)  # DivDis marginal term: KL(Bern(mean_i) || Bern(0.5)) per head
    kl = float(np.mean(mean * np.log(2 * mean) + (1 - mean) * np.log(2 * (1 - mean))))
    assert float(m["classifier/bce_neg"]) == pytest.approx(neg, rel=1e-4)
    assert float(m["classifier/bce_pos"]) == pytest.approx(pos, rel=1e-4)
    assert mi > 0.01
    assert float(m["classifier/mi"]) == pytest.approx(mi, rel=1e-3)
    assert float(m["classifier/marginal_kl"]) == pytest.approx(kl, rel=1e-3)
    assert float(total) == pytest.approx(neg + pos + 0.7 * (mi + 0.3 * kl), rel=1e-4)
    assert float(m["classifier/loss"]) == float(total)


def test_update_classifier_steps_adam():
    cfg = ClassifierConfig(n_heads=2, hidden_sizes=(8,), lr=1e-2)
    net = clf.make_classifier(cfg, UNIT)
    state, hp = _init(net), clf.hyperparams(cfg)
    sample = jax.jit(clf.sample_batch, static_argnums=(0, 1))
    batch = sample(cfg, UNIT, hp, jnp.zeros((16, 2)), jnp.zeros((1, 4, 2)), jax.random.key(1))
    new, metrics = jax.jit(lambda s, b: clf.update_classifier(cfg, net, OPT, hp, s, b))(
        state, batch
    )
    assert set(metrics) == {
        "classifier/loss",
        "classifier/bce_neg",
        "classifier/bce_pos",
        "classifier/mi",
        "classifier/marginal_kl",
    }

    @jax.jit
    def by_hand(params):
        grads = jax.grad(lambda p: clf.loss(cfg, net, hp, p, batch)[0])(params)
        updates, _ = optax.adam(1e-2).update(grads, optax.adam(1e-2).init(params), params)
        return optax.apply_updates(params, updates)

    # optax.adam(lr) is the optimiser's Adam scaling, then -lr from the hyperparameters
    # (equal up to the float rounding of two separately compiled programs).
    expected = by_hand(state.params)
    for a, b in zip(jax.tree.leaves(new.params), jax.tree.leaves(expected), strict=True):
        np.testing.assert_allclose(a, b, atol=1e-6)


def test_conditioning_goals_and_positives():
    env = BoxEnv([-18.0, 0.0], [18.0, 0.3], mask=[1.0, 0.0])
    key = jax.random.key(0)
    sample = jax.jit(clf.sample_conditioning_goals, static_argnums=(0, 1, 3))
    uniform = sample(ClassifierConfig(), env, key, 1000)
    assert uniform.shape == (1000, 2)
    assert np.all(uniform >= env.goal_low) and np.all(uniform <= env.goal_high)
    buffer = jnp.stack([jnp.arange(10.0), jnp.full(10, 0.1)], axis=-1)  # x in 0..9
    desired = jnp.full((2, 5, 2), -7.0)
    cfg = ClassifierConfig(goal_candidates="buffer_and_desired", eps=0.5)
    g = sample(cfg, env, key, 9, buffer, desired)
    assert g.shape == (9, 2)
    assert np.all(np.isin(np.asarray(g[:4, 0]), np.arange(10.0)))  # n // 2 from the buffer
    np.testing.assert_array_equal(g[4:], -7.0)  # the rest from the desired examples
    pos = jax.jit(clf.positive_examples, static_argnums=0)(env, uniform, cfg.eps, key)
    offset = np.asarray(pos - uniform)
    assert np.abs(offset[:, 0]).max() <= 0.5 and np.abs(offset[:, 0]).max() > 0.45
    np.testing.assert_array_equal(offset[:, 1], 0.0)  # masked coordinate: no noise


# --- the synthetic 2-D problem --------------------------------------------------------

_RADIUS = 0.3  # visited states: the disk of this radius around the origin
_DESIRED = jnp.array([0.7, 0.7])  # the one desired outcome


def _disk(key, n):
    k_r, k_a = jax.random.split(key)
    r = _RADIUS * jnp.sqrt(jax.random.uniform(k_r, (n,)))
    a = jax.random.uniform(k_a, (n,), maxval=2 * jnp.pi)
    return jnp.stack([r * jnp.cos(a), r * jnp.sin(a)], axis=-1)


def _train_synthetic(lams, uniform_dg=False, steps=300, batch=256, seed=0, mus=None):
    """Trains 2x64 classifiers, one per (lambda, mu) (vmapped), on the synthetic problem.

    Conditioning goals: the desired point itself, or (uniform_dg) D_G = U(bounds) as in
    D2C's default, through `sample_batch`. `mus`: the marginal weights (default 0: Eq. 5 alone).
    Returns the module and the parameters, stacked over `lams`.
    """
    cfg = ClassifierConfig(n_heads=2, hidden_sizes=(64, 64), batch_size=batch, eps=0.05)
    net = clf.make_classifier(cfg, UNIT)
    cond = jnp.broadcast_to(_DESIRED, (batch, 2))

    def train(lam, mu, key):
        hp = clf.hyperparams(cfg).replace(diversity_weight=lam, marginal_weight=mu)  # traced

        def body(state, key):
            k_neg, k_pos, k_uni = jax.random.split(key, 3)
            if uniform_dg:
                b = clf.sample_batch(
                    cfg, UNIT, hp, _disk(k_neg, batch), _DESIRED[None, None], k_pos
                )
                return clf.update_classifier(cfg, net, OPT, hp, state, b)
            b = clf.ClassifierBatch(
                negatives=_disk(k_neg, batch),
                positives=clf.positive_examples(UNIT, cond, hp.eps, k_pos),
                uniform=UNIT.sample_uniform_goals(k_uni, batch),
                cond_goals=cond,
                uniform_goals=cond,
            )
            return clf.update_classifier(cfg, net, OPT, hp, state, b)

        k_init, k_steps = jax.random.split(key)
        state = clf.init_classifier(net, OPT, 2, k_init)
        return jax.lax.scan(body, state, jax.random.split(k_steps, steps))[0].params

    run = jax.jit(jax.vmap(train, in_axes=(0, 0, None)))
    mus = np.zeros(len(lams)) if mus is None else mus
    return net, run(
        jnp.asarray(lams, jnp.float32), jnp.asarray(mus, jnp.float32), jax.random.key(seed)
    )


def _synthetic_stats(net, params):
    """p_pseudo and head disagreement inside the disk, at the desired point, unexplored."""
    xs = np.linspace(-1.0, 1.0, 41)
    grid = np.stack(np.meshgrid(xs, xs), axis=-1).reshape(-1, 2)
    inside = np.linalg.norm(grid, axis=1) < 0.9 * _RADIUS
    far = (np.linalg.norm(grid, axis=1) > 0.6) & (np.linalg.norm(grid - _DESIRED, axis=1) > 0.6)
    points = jnp.concatenate([jnp.asarray(grid), _DESIRED[None]])
    heads = np.asarray(jax.jit(clf.head_probs, static_argnums=0)(net, params, points, _DESIRED))
    h_in, h_far, h_des = heads[:-1][inside], heads[:-1][far], heads[-1]
    return {
        "p_inside": float(h_in.mean()),
        "p_desired": float(h_des.mean()),
        "p_unexplored": float(h_far.mean()),
        "dis_inside": float(np.abs(h_in[:, 0] - h_in[:, 1]).mean()),
        "dis_unexplored": float(np.abs(h_far[:, 0] - h_far[:, 1]).mean()),
    }


@pytest.mark.parametrize(
    "uniform_dg",
    [False, pytest.param(True, marks=pytest.mark.slow)],
    ids=["g=desired", "g~D_T"],
)
def test_synthetic_heads_disagree_only_off_the_data(uniform_dg):
    net, params = _train_synthetic(lams=(1.0, 0.0), uniform_dg=uniform_dg)
    diverse = _synthetic_stats(net, jax.tree.map(lambda x: x[0], params))
    plain = _synthetic_stats(net, jax.tree.map(lambda x: x[1], params))
    print(f"\nlambda=1: {diverse}\nlambda=0: {plain}")
    for s in (diverse, plain):
        assert s["p_inside"] < 0.05 and s["p_desired"] > 0.95
        assert s["dis_inside"] < 0.02
    # lambda = 1: far from both the visited disk and the desired point the heads split,
    # so p_pseudo lies between its values on the data. With D_G = U(bounds) the MI term
    # acts on (u, g) pairs with random g, so at the one g probed the split is narrower.
    assert diverse["dis_unexplored"] > (0.1 if uniform_dg else 0.3)
    assert diverse["dis_unexplored"] > 10 * diverse["dis_inside"]
    assert diverse["p_inside"] < diverse["p_unexplored"] < diverse["p_desired"]
    assert 0.05 < diverse["p_unexplored"] < 0.85
    # lambda = 0: the heads agree nearly everywhere.
    assert plain["dis_unexplored"] < 0.05
    assert diverse["dis_unexplored"] > 5 * plain["dis_unexplored"]


def test_marginal_term_makes_heads_split_under_uniform_dg():
    """With D_G = U(bounds) (D2C's default) the MI term alone barely splits the heads: a
    "near g" head is ~0 on almost every uniform (u, g) pair, so it is nearly constant there
    and MI is ~0 whatever the other head says. DivDis's marginal term forces one head onto
    "x is unvisited", so p_pseudo in unexplored space is ~0.5 (SPEC §3) instead of ~0."""
    net, params = _train_synthetic(lams=(1.0, 1.0), mus=(1.0, 0.0), uniform_dg=True)
    with_marginal = _synthetic_stats(net, jax.tree.map(lambda x: x[0], params))
    mi_only = _synthetic_stats(net, jax.tree.map(lambda x: x[1], params))
    print(f"\nmu=1: {with_marginal}\nmu=0: {mi_only}")
    for s in (with_marginal, mi_only):
        assert s["p_inside"] < 0.05 and s["p_desired"] > 0.95
    assert with_marginal["dis_unexplored"] > 0.3
    assert 0.2 < with_marginal["p_unexplored"] < 0.8
    assert with_marginal["dis_unexplored"] > 2 * mi_only["dis_unexplored"]
