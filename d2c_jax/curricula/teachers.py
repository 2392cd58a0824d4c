"""Teacher curricula over the goal space (issue 20): PLR and ALP-GMM (`--algo plr|alp_gmm`).

A teacher proposes one goal per episode from the env's goal bounds (never the walls) and
scores the episodes it gets back. Both follow psclklnk/currot's reference code (commit
4147270, `deep_sprl/teachers/plr/prioritized_level_replay.py` and
`deep_sprl/teachers/alp_gmm/alp_gmm.py`; docs/BASELINES.md cites each formula), with the
sparse reward of paper appendix A.1. An episode's return is its discounted sum of sparse
rewards, sum_t gamma^t 1[success at t + 1], the scale of our critic's values.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

from d2c_jax import config as config_lib
from d2c_jax.core.types import Metrics
from d2c_jax.curricula import curriculum, gmm
from d2c_jax.curricula.interface import Curriculum, CurriculumInputs

# --- shared ----------------------------------------------------------------------------


def episode_returns(success: jax.Array, gamma: float) -> jax.Array:
    """sum_t gamma^t r_t with r_t = 1[success after step t]: success (n, H) -> (n,)."""
    discounts = gamma ** jnp.arange(success.shape[1], dtype=jnp.float32)
    return success.astype(jnp.float32) @ discounts


class Teacher(Curriculum):
    """A goal-space teacher: sparse reward, no classifier, goals held for the episode."""

    reward = config_lib.ALGO_REWARDS["plr"]  # every teacher: the sparse reward (A.1)
    uses_classifier = False

    def episodes_feedback(self, episodes) -> tuple[jax.Array, jax.Array]:
        """(goals (n, d) each episode was given, returns (n,)) of this iteration."""
        return episodes.goal[:, 0], episode_returns(episodes.success, self.cfg.sac.gamma)

    def metrics(self, goals, key) -> Metrics:
        """The `curriculum/*` metrics of goals (K, d) against fresh desired examples."""
        slots = curriculum.goal_slots(self.env, goals.shape[0], key)
        return curriculum.proposal_metrics(goals, slots, 0.0, True, True)


# --- PLR ---------------------------------------------------------------------------------


@struct.dataclass
class PLRState:
    """PLR's level buffer (N levels) and what it last proposed (K slots)."""

    goals: jax.Array  # (N, d) the buffered goals
    scores: jax.Array  # (N,) float32 each level's learning potential
    staleness: jax.Array  # (N,) float32 episodes since each level was last played
    max_return: jax.Array  # (N,) float32 the best return seen on each level
    filled: jax.Array  # (N,) bool which entries hold a level
    proposed: jax.Array  # (K,) int32 the buffer index of each proposal; -1: a new goal


def plr_replay_distribution(scores, staleness, filled, beta: float, rho: float) -> jax.Array:
    """(1 - rho) P_S + rho P_C over the filled levels: P_S by rank, softmax(-log(rank) /
    beta), P_C by staleness share (plr:37-53). (N,) -> (N,), 0 on empty entries."""
    order = jnp.argsort(jnp.where(filled, -scores, jnp.inf))  # best first, empties last
    rank = jnp.empty_like(order).at[order].set(jnp.arange(1, order.shape[0] + 1))
    logits = jnp.where(filled, -jnp.log(rank.astype(jnp.float32)) / beta, -jnp.inf)
    by_score = jax.nn.softmax(logits)
    stale = jnp.where(filled, staleness, 0.0)
    by_staleness = jnp.where(stale.sum() > 0, stale / jnp.maximum(stale.sum(), 1e-12), by_score)
    return (1.0 - rho) * by_score + rho * by_staleness


class PLRTeacher(Teacher):
    """Prioritized Level Replay (Jiang et al. 2021) over goals (`--algo plr`).

    Each proposal replays a buffered goal with probability `replay_rate` (sampled by
    `plr_replay_distribution`), else draws a new one uniformly over the goal bounds. An
    episode's score is mean_t max(R_max - V(s_t, g), 0) over its states, V our critic's
    value (plr:55-85: the reference's score, a MaxMC form of positive value loss). A new
    goal enters a free entry, or replaces the lowest score if it scores higher."""

    needs_value = True

    def init(self, key) -> PLRState:
        n, d, k = self.cfg.teachers.plr_buffer_size, self.env.goal_dim, self.cfg.curriculum.n_slots
        return PLRState(
            goals=jnp.zeros((n, d), jnp.float32),
            scores=jnp.zeros((n,), jnp.float32),
            staleness=jnp.zeros((n,), jnp.float32),
            max_return=jnp.zeros((n,), jnp.float32),
            filled=jnp.zeros((n,), bool),
            proposed=jnp.full((k,), -1, jnp.int32),
        )

    def propose(self, state: PLRState, inputs: CurriculumInputs, key):
        t, k = self.cfg.teachers, self.cfg.curriculum.n_slots
        k_coin, k_pick, k_new, k_metrics = jax.random.split(key, 4)
        probs = plr_replay_distribution(
            state.scores, state.staleness, state.filled, t.plr_beta, t.plr_rho
        )
        picks = jax.random.choice(k_pick, probs.shape[0], (k,), p=probs)
        replay = jax.random.uniform(k_coin, (k,)) < t.plr_replay_rate
        replay = replay & state.filled.any()
        goals = jnp.where(
            replay[:, None], state.goals[picks], self.env.sample_uniform_goals(k_new, k)
        )
        state = state.replace(proposed=jnp.where(replay, picks, -1).astype(jnp.int32))
        return goals, self.metrics(goals, k_metrics), state

    def observe(self, state: PLRState, episodes, inputs: CurriculumInputs):
        goals, returns = self.episodes_feedback(episodes)
        obs = episodes.obs  # (n, H + 1, o)
        values = inputs.value_fn(
            obs, jnp.broadcast_to(goals[:, None], obs.shape[:2] + goals.shape[-1:])
        )
        n = goals.shape[0]
        proposed = state.proposed[jnp.arange(n) % state.proposed.shape[0]]

        def one(s: PLRState, episode):
            goal, ret, value, index = episode
            replayed = index >= 0
            i = jnp.maximum(index, 0)
            best = jnp.where(replayed, jnp.maximum(s.max_return[i], ret), ret)
            score = jnp.mean(jnp.maximum(best - value, 0.0))
            free = jnp.argmin(s.filled)  # the first empty entry (argmin of bool)
            weakest = jnp.argmin(jnp.where(s.filled, s.scores, jnp.inf))
            full = s.filled.all()
            enters = replayed | ~full | (score > s.scores[weakest])
            slot = jnp.where(replayed, i, jnp.where(full, weakest, free))
            stale = s.staleness + 1.0

            def put(x, v):
                return jnp.where(enters, x.at[slot].set(v), x)

            s = s.replace(
                goals=put(s.goals, goal), scores=put(s.scores, score),
                staleness=put(stale, 0.0), max_return=put(s.max_return, best),
                filled=put(s.filled, True),
            )  # fmt: skip
            return s, score

        state, scores = jax.lax.scan(one, state, (goals, returns, values, proposed))
        return state, {
            "plr/score": scores.mean(),
            "plr/levels": state.filled.sum().astype(jnp.float32),
        }


# --- ALP-GMM -------------------------------------------------------------------------------


@struct.dataclass
class ALPGMMState:
    """ALP-GMM's history, its (goal, ALP) tasks and its fitted mixture."""

    history_goals: jax.Array  # (M, d) goals of past episodes (a ring)
    history_returns: jax.Array  # (M,) float32 their returns
    tasks: jax.Array  # (F, d + 1) the last F (goal, ALP) rows (a ring)
    episodes: jax.Array  # () int32 episodes seen
    mixture: gmm.Mixture  # k_max components in d + 1 dimensions (unused ones: weight 0)
    fitted: jax.Array  # () bool a mixture has been fitted


def absolute_learning_progress(goal, ret, history_goals, history_returns, count) -> jax.Array:
    """|R - R(c')| for the nearest earlier goal c' (alp_gmm.py:18-39); 0 until more than 5
    episodes are in the history. goal (d,), history (M, d), (M,), count () -> ()."""
    filled = jnp.arange(history_goals.shape[0]) < count
    dist = jnp.where(filled, jnp.linalg.norm(history_goals - goal, axis=-1), jnp.inf)
    return jnp.where(count > 5, jnp.abs(ret - history_returns[jnp.argmin(dist)]), 0.0)


def aic(x: jax.Array, mixture: gmm.Mixture, n_components: int) -> jax.Array:
    """Akaike's criterion -2 n mean_ll + 2 p of a full-covariance mixture (scikit-learn's)."""
    n, d = x.shape
    mean_ll, _ = gmm.e_step(x, mixture, jnp.ones(n))
    params = (n_components - 1) + n_components * d + n_components * d * (d + 1) // 2
    return -2.0 * n * mean_ll + 2.0 * params


def initial_mixture(x: jax.Array, k: int, key) -> gmm.Mixture:
    """k distinct random rows as means, the data's covariance, equal weights."""
    means = x[jax.random.choice(key, x.shape[0], (k,), replace=False)]
    cov = jnp.cov(x.T) + 1e-6 * jnp.eye(x.shape[1])
    return gmm.Mixture(jnp.full((k,), 1.0 / k), means, jnp.broadcast_to(cov, (k,) + cov.shape))


def pad_mixture(mixture: gmm.Mixture, k_max: int) -> gmm.Mixture:
    """The mixture with k_max components: the extra ones weight 0, identity covariance."""
    pad = k_max - mixture.weights.shape[0]
    eye = jnp.broadcast_to(jnp.eye(mixture.means.shape[1]), (pad,) + mixture.covariances.shape[1:])
    return gmm.Mixture(
        jnp.pad(mixture.weights, (0, pad)),
        jnp.pad(mixture.means, ((0, pad), (0, 0))),
        jnp.concatenate([mixture.covariances, eye]),
    )


def fit_every_k(
    x: jax.Array, k_max: int, key, t: config_lib.TeachersConfig
) -> tuple[list[gmm.Mixture], jax.Array]:
    """EM for k = 2..k_max components (at most one per row): the fits, each padded to
    k_max (weight 0), and their AIC (n_k,), inf where the fit is not usable.

    A fit whose parameters or AIC are not finite is not usable: in float32 a component
    that collapses onto a few rows can leave a covariance Cholesky cannot factor
    (reg_covar 1e-6 is scikit-learn's float64 default), and argmin would pick its NaN."""
    fits, scores = [], []
    ks = range(2, min(k_max, x.shape[0]) + 1)
    for k, k_key in zip(ks, jax.random.split(key, len(ks)), strict=True):
        fitted = gmm.fit(x, initial_mixture(x, k, k_key), reg_covar=t.alp_reg_covar,
                         tol=t.alp_tol, max_iter=t.alp_max_iter).mixture  # fmt: skip
        score = aic(x, fitted, k)
        usable = jnp.isfinite(score) & jnp.all(
            jnp.stack([jnp.isfinite(leaf).all() for leaf in fitted])
        )
        fits.append(pad_mixture(fitted, k_max))
        scores.append(jnp.where(usable, score, jnp.inf))
    return fits, jnp.stack(scores)


def least_aic(fits: list[gmm.Mixture], scores: jax.Array) -> tuple[gmm.Mixture, jax.Array]:
    """The fit of least AIC among `fit_every_k`'s, and () bool: some fit was usable."""
    best = jnp.argmin(scores)
    mixture = jax.tree.map(lambda *xs: jnp.stack(xs)[best], *fits)
    return mixture, jnp.isfinite(scores[best])


def fit_best_mixture(
    x: jax.Array, k_max: int, key, t: config_lib.TeachersConfig
) -> tuple[gmm.Mixture, jax.Array]:
    """EM for k = 2..k_max components, the least AIC kept, padded to k_max (weight 0).
    Returns (mixture, () bool some fit was usable); unusable fits never win
    (`fit_every_k`)."""
    return least_aic(*fit_every_k(x, k_max, key, t))


class ALPGMMTeacher(Teacher):
    """ALP-GMM (Portelas et al. 2019) over goals (`--algo alp_gmm`).

    Every episode's absolute learning progress is |R - R(c')| for the nearest earlier goal
    c'; every `alp_fit_rate` episodes a full-covariance mixture is fitted by EM on the last
    `alp_fit_rate` (goal, ALP) rows, k = 2..`alp_max_components` chosen by AIC. Goals are
    drawn uniformly with probability `alp_random_ratio` (and until the first fit), else
    from a component chosen in proportion to its mean ALP, clipped to the goal bounds."""

    def init(self, key) -> ALPGMMState:
        t, d = self.cfg.teachers, self.env.goal_dim
        k = t.alp_max_components
        return ALPGMMState(
            history_goals=jnp.zeros((t.alp_history, d), jnp.float32),
            history_returns=jnp.zeros((t.alp_history,), jnp.float32),
            tasks=jnp.zeros((t.alp_fit_rate, d + 1), jnp.float32),
            episodes=jnp.zeros((), jnp.int32),
            mixture=gmm.Mixture(
                jnp.full((k,), 1.0 / k),
                jnp.zeros((k, d + 1)),
                jnp.broadcast_to(jnp.eye(d + 1), (k, d + 1, d + 1)),
            ),  # fmt: skip
            fitted=jnp.zeros((), bool),
        )

    def propose(self, state: ALPGMMState, inputs: CurriculumInputs, key):
        t, k = self.cfg.teachers, self.cfg.curriculum.n_slots
        k_coin, k_comp, k_draw, k_uni, k_metrics = jax.random.split(key, 5)
        mix = state.mixture
        alp = jnp.maximum(mix.means[:, -1], 0.0) * (mix.weights > 0)
        logits = jnp.log(jnp.where(alp.sum() > 0, alp, (mix.weights > 0).astype(jnp.float32)))
        comp = jax.random.categorical(k_comp, logits, shape=(k,))
        chol = jnp.linalg.cholesky(mix.covariances[comp])  # (K, d + 1, d + 1)
        draws = mix.means[comp] + jnp.einsum(
            "kij,kj->ki", chol, jax.random.normal(k_draw, (k, chol.shape[-1]))
        )
        random = (jax.random.uniform(k_coin, (k,)) < t.alp_random_ratio) | ~state.fitted
        goals = jnp.where(
            random[:, None],
            self.env.sample_uniform_goals(k_uni, k),
            self.env.clip_goal(draws[:, :-1]),
        )
        return goals, self.metrics(goals, k_metrics), state

    def observe(self, state: ALPGMMState, episodes, inputs: CurriculumInputs):
        t = self.cfg.teachers
        goals, returns = self.episodes_feedback(episodes)

        def one(s: ALPGMMState, episode):
            goal, ret = episode
            count = jnp.minimum(s.episodes, t.alp_history)
            alp = absolute_learning_progress(goal, ret, s.history_goals, s.history_returns, count)
            h, f = s.episodes % t.alp_history, s.episodes % t.alp_fit_rate
            s = s.replace(
                history_goals=s.history_goals.at[h].set(goal),
                history_returns=s.history_returns.at[h].set(ret),
                tasks=s.tasks.at[f].set(jnp.concatenate([goal, alp[None]])),
                episodes=s.episodes + 1,
            )
            return s, alp

        before = state.episodes
        state, alps = jax.lax.scan(one, state, (goals, returns))
        due = (state.episodes // t.alp_fit_rate) > (before // t.alp_fit_rate)
        state = jax.lax.cond(due, lambda: self._refit(state, inputs.key), lambda: state)
        return state, {
            "alp_gmm/alp": alps.mean(),
            "alp_gmm/fitted": state.fitted.astype(jnp.float32),
        }

    def _refit(self, state: ALPGMMState, key) -> ALPGMMState:
        """A new mixture; the previous one (or none) stays when no fit was usable."""
        mixture, usable = fit_best_mixture(
            state.tasks, self.cfg.teachers.alp_max_components, key, self.cfg.teachers
        )
        mixture = jax.tree.map(lambda new, old: jnp.where(usable, new, old), mixture, state.mixture)
        return state.replace(mixture=mixture, fitted=state.fitted | usable)
