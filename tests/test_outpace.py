"""OUTPACE's parts (`--algo outpace`, issue 19): meta-NML, the AIM potential, the run."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

import envs
from d2c_jax import config
from d2c_jax.curricula import aim, meta_nml
from d2c_jax.training import cli, loop
from d2c_jax.training import logging as logging_lib


def _toy_data():
    """1-D: negatives on [-2, 0], positives on [1, 2] (64 each)."""
    neg = jax.random.uniform(jax.random.key(1), (64, 1), minval=-2.0, maxval=0.0)
    pos = jax.random.uniform(jax.random.key(2), (64, 1), minval=1.0, maxval=2.0)
    labels = jnp.concatenate([jnp.zeros(64, jnp.int32), jnp.ones(64, jnp.int32)])
    return jnp.concatenate([neg, pos]), labels


def _brute_force_cnml(net, params, x, y, query, s: meta_nml.MetaNMLSettings, steps=500):
    """CNML by refitting: from params, fit the distance-weighted data plus (query, c) for
    c = 0 and 1 to convergence (Adam), q_c = p_c(query); p = q_1 / (q_0 + q_1)."""

    def q(label):
        w = meta_nml.distance_weights(query, x, s.distance_scale)
        bx, by, bw = meta_nml._with_query(query, label, s.query_weight_outer, x, y, w)
        opt = optax.adam(1e-2)

        def body(carry, _):
            p, st = carry
            g = jax.grad(meta_nml.weighted_cross_entropy, argnums=1)(net, p, bx, by, bw)
            updates, st = opt.update(g, st, p)
            return (optax.apply_updates(p, updates), st), None

        (fitted, _), _ = jax.lax.scan(body, (params, opt.init(params)), None, length=steps)
        return jax.nn.softmax(net.apply(fitted, query))[label]

    q0, q1 = q(0), q(1)
    return q1 / (q0 + q1)


def test_meta_nml_matches_brute_force_cnml_on_a_1d_toy():
    s = meta_nml.MetaNMLSettings(
        inner_step=0.5, context_points=31, query_weight_inner=1 / 8,
        query_weight_outer=0.5, distance_scale=1.0,
    )  # fmt: skip
    net = meta_nml.Classifier(hidden_sizes=(32,))
    x, y = _toy_data()
    params = net.init(jax.random.key(0), x[:1])
    opt = optax.adam(1e-2)
    state = opt.init(params)
    step = jax.jit(
        lambda p, o, k: meta_nml.meta_train_step(net, opt, p, o, (x, y), (x, y), k, s, 16)
    )
    for i in range(300):
        params, state, _ = step(params, state, jax.random.key(100 + i))
    queries = jnp.linspace(-4.0, 5.0, 19)[:, None]
    meta = meta_nml.nml_probabilities(net, params, queries, x, y, jax.random.key(7), s)
    brute = jax.vmap(lambda q: _brute_force_cnml(net, params, x, y, q, s))(queries)
    assert float(jnp.abs(meta - brute).mean()) < 0.15, (meta, brute)
    far = (queries[:, 0] <= -3.0) | (queries[:, 0] >= 3.0)  # no data within a unit
    np.testing.assert_allclose(meta[far], 0.5, atol=0.05)
    np.testing.assert_allclose(brute[far], 0.5, atol=0.05)
    inside_neg = (queries[:, 0] >= -1.5) & (queries[:, 0] <= -0.5)
    inside_pos = queries[:, 0] == 1.5
    assert bool((meta[inside_neg] < 0.2).all()) and bool((meta[inside_pos] > 0.8).all())


def test_aim_hinge_penalty_by_hand():
    """With a constant-free check: the hinge is max(|D(s') - D(s)| - L, 0)^2 per pair."""
    net = aim.PotentialEnsemble(1, (4,), (0.0,), (1.0,))
    params = net.init(jax.random.key(0), jnp.zeros((1, 1)), jnp.zeros((1, 1)))
    ag, nxt, g = jnp.array([[0.0], [0.5]]), jnp.array([[1.0], [0.5]]), jnp.array([[1.0], [1.0]])
    loss, (d_target, d_now) = aim.aim_loss(net, params, ag, nxt, g, g, 0.01, 3.0)
    d_next = net.apply(params, nxt, g)
    hinge = jnp.maximum(jnp.abs(d_next - d_now) - 0.01, 0.0) ** 2
    expected = d_next.mean() - d_target.mean() + 3.0 * hinge.mean()
    np.testing.assert_allclose(loss, expected, rtol=1e-6)
    assert float(hinge[0, 1]) == 0.0  # s' = s: no change, no penalty


def test_aim_potential_grows_with_time_steps_on_a_chain():
    """A chain 0 -> 1 -> ... -> 9 walked one step per transition, goal at its end: the
    potential rises along the chain, by at most the Lipschitz constant per step (with a
    stiff penalty), i.e. it measures the distance to the goal in time steps."""
    n, lipschitz = 10, 0.1
    xs = jnp.arange(n, dtype=jnp.float32)[:, None]
    goal = jnp.full((n - 1, 1), n - 1.0)
    net = aim.PotentialEnsemble(3, (32, 32), (0.0,), (float(n - 1),))
    params = net.init(jax.random.key(0), xs[:1], xs[:1])
    opt = optax.adam(1e-3)
    state = opt.init(params)

    @jax.jit
    def step(params, state, key):
        target = goal + 0.1 * jax.random.normal(key, goal.shape)
        batch = (xs[:-1], xs[1:], goal, target)
        return aim.update(net, opt, params, state, batch, lipschitz, 1000.0)

    for i in range(1500):
        params, state, _, _ = step(params, state, jax.random.key(i))
    d = np.asarray(aim.potential(net, params, xs, jnp.full((n, 1), n - 1.0)))
    steps = np.diff(d)
    assert (steps > 0).all(), d
    assert steps.max() <= 1.1 * lipschitz and steps.min() >= 0.8 * lipschitz, steps


# --- the run ---------------------------------------------------------------------------


def _train(out, *extra):
    argv = ["--env", "medium_maze", "--preset", "tiny", "--algo", "outpace", *extra]
    cfg, _, _ = cli.parse_args(argv)
    assert loop.train(cfg, out, quiet=True) == 0
    return [{k: v for k, v in r.items() if not k.startswith("time/")}
            for r in logging_lib.read_metrics(out / "metrics.jsonl")]  # fmt: skip


@pytest.mark.slow  # minutes cold on 2 cores; the default suite trains OUTPACE once (test_algos)
def test_outpace_trains_matches_and_resumes_like_an_uninterrupted_run(tmp_path):
    extra = ("--curriculum.rematch-every", "400", "--total-steps", "800")
    full = _train(tmp_path / "full", *extra)
    assert any(r["curriculum/pool_full"] == 1.0 for r in full)
    for key in ("outpace/aim_loss", "outpace/nml_loss", "sac/reward_mean", "eval/success"):
        assert np.isfinite(full[-1][key]), key
    assert not any(k.startswith("classifier/") for k in full[-1])
    path = tmp_path / "resumed"
    _train(path, "--curriculum.rematch-every", "400", "--total-steps", "400")
    cfg, _, _ = cli.parse_args(
        ["--env", "medium_maze", "--preset", "tiny", "--algo", "outpace", *extra]
    )
    assert loop.train(cfg, path, resume=True, quiet=True) == 0
    resumed = [{k: v for k, v in r.items() if not k.startswith("time/")}
               for r in logging_lib.read_metrics(path / "metrics.jsonl")]  # fmt: skip
    assert resumed == full


def test_outpace_settings_follow_the_authors_per_env():
    push = config.with_algo(config.preset("sawyer_push", "quick"), "outpace")
    assert push.outpace.cost_lipschitz == 0.5 and push.outpace.goal_noise_std == 0.05
    assert push.curriculum.pool_min_move == 0.02 and push.replay.walk_fraction == 0.2
    spiral = config.with_algo(config.preset("spiral_maze", "paper"), "outpace")
    assert spiral.outpace.aim_penalty == 50.0 and spiral.outpace.nml_hidden_sizes == (2048, 2048)
    ant = config.with_algo(config.preset("ant", "quick"), "outpace")
    assert ant.curriculum.cost_stride == 6 and ant.curriculum.archive_size == 0


@pytest.mark.slow
@pytest.mark.parametrize("env_name", [e for e in envs.ENV_NAMES if e != "medium_maze"])
def test_outpace_trains_tiny_on_every_env(env_name, tmp_path):
    cfg, _, _ = cli.parse_args(["--env", env_name, "--preset", "tiny", "--algo", "outpace"])
    assert loop.train(cfg, tmp_path / "run", quiet=True) == 0


def test_outpace_critic_stops_at_success_and_d2cs_does_not():
    """OUTPACE's own code ends the critic's episode where the relabelled goal is reached
    (done_on_success, consider_done_true_in_critic); D2C and the other baselines keep
    bootstrapping (SPEC §4)."""
    from d2c_jax.training import agent as agent_lib

    maze = envs.make("medium_maze")
    ag = jnp.array([[16.0, 16.3], [16.0, 16.6]])  # 0.3 and 0.6 from the goal (radius 0.5)
    goal = jnp.array([[16.0, 16.0], [16.0, 16.0]])
    for algo in ("outpace", "d2c", "her", "hgg"):
        cfg = config.with_algo(config.preset("medium_maze", "tiny"), algo)
        terminal_fn = agent_lib.Agent(cfg, maze).terminal_fn()
        if algo == "outpace":
            np.testing.assert_array_equal(terminal_fn(ag, goal), [1.0, 0.0])
        else:
            assert terminal_fn is None, algo
    # `sac.terminal_on_success` gives D2C OUTPACE's terminal
    cfg = config.preset("medium_maze", "tiny")
    cfg = dataclasses.replace(cfg, sac=dataclasses.replace(cfg.sac, terminal_on_success=True))
    np.testing.assert_array_equal(agent_lib.Agent(cfg, maze).terminal_fn()(ag, goal), [1.0, 0.0])
