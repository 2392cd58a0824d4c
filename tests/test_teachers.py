"""The goal-space teachers (`--algo currot|plr|alp_gmm|vds`, issue 20): rules by hand, and
runs (CURROT's own rules: tests/test_currot.py)."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs
from d2c_jax import config
from d2c_jax.core import rollout
from d2c_jax.curricula import interface, teachers
from d2c_jax.training import cli, loop
from d2c_jax.training import logging as logging_lib

TEACHERS = config.TEACHER_ALGOS


@pytest.fixture(scope="module")
def maze():
    return envs.make("medium_maze")


def _teacher(maze, algo, **teacher_fields):
    cfg = config.with_algo(config.preset("medium_maze", "tiny"), algo)
    cfg = dataclasses.replace(cfg, teachers=dataclasses.replace(cfg.teachers, **teacher_fields))
    return cfg, interface.make_curriculum(cfg, maze, None)


def _episodes(goals, first_success, horizon=5, obs_dim=3):
    """Episodes whose goal is held and whose success starts at `first_success` (H: never)."""
    n = goals.shape[0]
    t = jnp.arange(horizon)
    success = t[None] >= jnp.asarray(first_success)[:, None]
    return rollout.Episodes(
        obs=jnp.zeros((n, horizon + 1, obs_dim)),
        achieved_goal=jnp.zeros((n, horizon + 1, goals.shape[1])),
        action=jnp.zeros((n, horizon, 2)),
        goal=jnp.broadcast_to(goals[:, None], (n, horizon, goals.shape[1])),
        success=success,
        walk_start=jnp.full((n,), horizon, jnp.int32),
    )


def test_episode_return_is_the_discounted_sum_of_sparse_rewards():
    success = jnp.array([[False, True, True], [False, False, False]])
    np.testing.assert_allclose(teachers.episode_returns(success, 0.5), [0.5 + 0.25, 0.0])


def test_plr_replay_distribution_by_hand():
    scores = jnp.array([3.0, 1.0, 2.0, 9.0])
    staleness = jnp.array([1.0, 2.0, 3.0, 5.0])
    filled = jnp.array([True, True, True, False])  # the 4th entry is empty
    p = teachers.plr_replay_distribution(scores, staleness, filled, beta=1.0, rho=0.5)
    by_rank = np.array([1.0, 1 / 3, 1 / 2]) / (1 + 1 / 3 + 1 / 2)  # ranks 1, 3, 2
    by_staleness = np.array([1.0, 2.0, 3.0]) / 6.0
    np.testing.assert_allclose(p[:3], 0.5 * by_rank + 0.5 * by_staleness, rtol=1e-5)
    assert float(p[3]) == 0.0


def test_plr_buffer_inserts_scores_and_replaces_the_weakest(maze):
    cfg, plr = _teacher(maze, "plr", plr_buffer_size=2)
    gamma = cfg.sac.gamma
    state = plr.init(jax.random.key(0)).replace(proposed=jnp.array([-1, -1, -1, -1], jnp.int32))
    inputs = interface.CurriculumInputs(
        None, None, None, None, None, None, lambda obs, g: jnp.zeros(obs.shape[:-1]), None
    )  # V = 0 everywhere: an episode's score is its return
    goals = jnp.array([[1.0, 1.0], [2.0, 2.0], [3.0, 3.0], [4.0, 4.0]])
    first = jnp.array([5, 4, 2, 5])  # returns 0, gamma^4, gamma^2 + gamma^3 + gamma^4, 0
    state, _ = plr.observe(state, _episodes(goals, first), inputs)
    r1, r2 = gamma**4, gamma**2 + gamma**3 + gamma**4
    # Episodes 0 and 1 fill the two entries; 2 replaces the weakest (episode 0, score 0);
    # 3 (score 0) does not beat the weakest left (r1) and is dropped.
    np.testing.assert_allclose(state.goals, [[3.0, 3.0], [2.0, 2.0]])
    np.testing.assert_allclose(state.scores, [r2, r1], rtol=1e-6)
    np.testing.assert_allclose(state.staleness, [1.0, 2.0])  # played 1 and 2 episodes ago


def test_plr_replays_only_buffered_goals_at_replay_rate_one(maze):
    _, plr = _teacher(maze, "plr", plr_replay_rate=1.0)
    state = plr.init(jax.random.key(0))
    state = state.replace(
        goals=state.goals.at[:2].set(jnp.array([[1.0, 2.0], [3.0, 4.0]])),
        filled=state.filled.at[:2].set(True),
        scores=state.scores.at[:2].set(jnp.array([1.0, 0.5])),
    )
    goals, _, state = plr.propose(state, None, jax.random.key(1))
    assert bool(jnp.all((state.proposed == 0) | (state.proposed == 1)))
    np.testing.assert_allclose(goals, state.goals[state.proposed])


def test_alp_is_the_return_change_at_the_nearest_earlier_goal():
    history = jnp.array([[0.0, 0.0], [5.0, 5.0], [1.0, 0.0], [9, 9], [8, 8], [7, 7]])
    returns = jnp.array([1.0, 2.0, 4.0, 0.0, 0.0, 0.0])
    alp = teachers.absolute_learning_progress(jnp.array([1.2, 0.1]), 10.0, history, returns, 6)
    assert float(alp) == pytest.approx(6.0)  # nearest is (1, 0) with return 4
    young = teachers.absolute_learning_progress(jnp.array([1.2, 0.1]), 10.0, history, returns, 5)
    assert float(young) == 0.0  # OUTPACE's reference waits for more than 5 episodes


def test_alp_gmm_discards_fits_that_are_not_finite_and_keeps_its_mixture(maze):
    """A quick medium_maze run stopped at 60k steps on NaN goals: in float32 the EM of
    some k collapsed a component onto a few rows, and the least-AIC pick took its NaN.
    Here 150 identical rows and no reg_covar make such collapses certain: a fit that is
    not finite must lose, and when no fit is usable the previous mixture stays."""
    # k = 2..4 (not the preset's 2..10): each k's EM while_loop compiles on its own when
    # run eagerly, and k = 4 already collapses here.
    cfg, alp = _teacher(maze, "alp_gmm", alp_reg_covar=0.0, alp_max_components=4)
    rng = np.random.default_rng(0)
    spread = np.concatenate([rng.uniform(-18, 18, (50, 2)), rng.uniform(0, 1, (50, 1))], 1)
    rows = jnp.asarray(np.concatenate([np.tile([[1.0, 1.0, 0.0]], (150, 1)), spread]), jnp.float32)
    # The fits of k = 2..4 that fit_best_mixture chooses from (fit_every_k), each once.
    fits, scores = teachers.fit_every_k(rows, 4, jax.random.key(3), cfg.teachers)
    assert len(fits) == 3
    finite = [all(bool(jnp.isfinite(leaf).all()) for leaf in fit) for fit in fits]
    assert not all(finite), finite  # the case is real
    mixture, usable = teachers.least_aic(fits, scores)
    assert bool(usable) == any(finite)
    if any(finite):
        assert all(bool(jnp.isfinite(leaf).all()) for leaf in mixture)
    state = alp.init(jax.random.key(0))
    kept = alp._refit(state.replace(tasks=rows.at[0, 0].set(jnp.nan)), jax.random.key(1))
    assert not bool(kept.fitted)  # no fit of NaN rows is usable: the mixture stays
    for new, old in zip(kept.mixture, state.mixture, strict=True):
        np.testing.assert_array_equal(new, old)


def test_alp_gmm_samples_where_learning_progresses(maze):
    """(goal, ALP) rows with progress only near (10, 10): after a fit, most non-random
    goals come from there."""
    _, alp = _teacher(maze, "alp_gmm", alp_fit_rate=200, alp_max_components=4)
    state = alp.init(jax.random.key(0))
    k_a, k_b = jax.random.split(jax.random.key(1))
    near = jnp.array([10.0, 10.0]) + jax.random.normal(k_a, (100, 2))
    far = jax.random.uniform(k_b, (100, 2), minval=-16.0, maxval=16.0)
    rows = jnp.concatenate([
        jnp.concatenate([near, jnp.full((100, 1), 5.0)], axis=1),
        jnp.concatenate([far, jnp.zeros((100, 1))], axis=1),
    ])  # fmt: skip
    state = alp._refit(state.replace(tasks=rows), jax.random.key(2))
    assert bool(state.fitted)
    hits = []
    for i in range(10):
        goals, _, _ = alp.propose(state, None, jax.random.key(10 + i))
        hits.append(np.linalg.norm(np.asarray(goals) - 10.0, axis=-1) < 4.0)
    assert np.mean(hits) >= 0.6, np.mean(hits)  # 80% from the mixture, nearly all near


# --- runs ---------------------------------------------------------------------------------


def _train(algo, out, *extra):
    cfg, _, _ = cli.parse_args(["--env", "medium_maze", "--preset", "tiny", "--algo", algo, *extra])
    assert loop.train(cfg, out, quiet=True) == 0
    return [{k: v for k, v in r.items() if not k.startswith("time/")}
            for r in logging_lib.read_metrics(out / "metrics.jsonl")]  # fmt: skip


# Minutes cold on 2 cores: the default suite trains each teacher once (tests/test_algos.py)
# and checks a curriculum state's checkpointing on a probe curriculum.
@pytest.mark.slow
@pytest.mark.parametrize("algo", TEACHERS)
def test_teacher_trains_and_resumes_like_an_uninterrupted_run(algo, tmp_path):
    extra = ("--teachers.alp-fit-rate", "8", "--total-steps", "800")
    full = _train(algo, tmp_path / "full", *extra)
    assert np.isfinite(full[-1]["eval/success"]) and 0 <= full[-1]["sac/reward_mean"] <= 1
    path = tmp_path / "resumed"
    _train(algo, path, "--teachers.alp-fit-rate", "8", "--total-steps", "400")
    cfg, _, _ = cli.parse_args(["--env", "medium_maze", "--preset", "tiny", "--algo", algo, *extra])
    assert loop.train(cfg, path, resume=True, quiet=True) == 0
    resumed = [{k: v for k, v in r.items() if not k.startswith("time/")}
               for r in logging_lib.read_metrics(path / "metrics.jsonl")]  # fmt: skip
    assert resumed == full
    if algo == "alp_gmm":
        assert full[-1]["alp_gmm/fitted"] == 1.0  # 8 episodes, a fit every 8


@pytest.mark.slow
@pytest.mark.parametrize("algo", TEACHERS)
@pytest.mark.parametrize("env_name", [e for e in envs.ENV_NAMES if e != "medium_maze"])
def test_teacher_trains_tiny_on_every_env(env_name, algo, tmp_path):
    cfg, _, _ = cli.parse_args(["--env", env_name, "--preset", "tiny", "--algo", algo])
    assert loop.train(cfg, tmp_path / "run", quiet=True) == 0


def test_vds_samples_in_proportion_to_disagreement():
    from d2c_jax.curricula import vds

    std = jnp.array([0.0, 1.0, 3.0, 6.0])
    picks = np.asarray(vds.sample_by_disagreement(std, 40_000, jax.random.key(0)))
    freq = np.bincount(picks, minlength=4) / picks.size
    np.testing.assert_allclose(freq, [0.0, 0.1, 0.3, 0.6], atol=0.01)
    uniform = np.asarray(vds.sample_by_disagreement(jnp.zeros(4), 40_000, jax.random.key(1)))
    np.testing.assert_allclose(np.bincount(uniform) / uniform.size, 0.25, atol=0.01)


def test_vds_td_loss_is_a_semi_gradient_without_target_network():
    """The target r + gamma Q(s', a') comes from the same ensemble but carries no gradient."""
    from d2c_jax.curricula import vds

    net = vds.QEnsemble(3, (8,))
    k = jax.random.split(jax.random.key(0), 6)
    feats, nxt = jax.random.normal(k[0], (16, 4)), jax.random.normal(k[1], (16, 4))
    act, nact = jax.random.normal(k[2], (16, 2)), jax.random.normal(k[3], (16, 2))
    reward = (jax.random.uniform(k[4], (16,)) < 0.3).astype(jnp.float32)
    params = net.init(k[5], feats, act)
    target = reward + 0.9 * net.apply(params, nxt, nact)  # (3, 16), held fixed

    def fixed_target_loss(p):
        return jnp.mean((net.apply(p, feats, act) - target) ** 2, axis=-1).sum()

    loss, grads = jax.value_and_grad(vds.td_loss, argnums=1)(
        net, params, feats, act, reward, nxt, nact, 0.9
    )
    ref_loss, ref_grads = jax.value_and_grad(fixed_target_loss)(params)
    np.testing.assert_allclose(loss, ref_loss, rtol=1e-6)
    for a, b in zip(jax.tree.leaves(grads), jax.tree.leaves(ref_grads), strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-7)
