"""CURROT (Klink et al. 2022) as a teacher over goals (`--algo currot`, issue 20).

The curriculum is a set of N particles in the goal space. Each episode trains on a
particle drawn uniformly (plus a tiny jitter). Every `currot_episodes_per_update`
episodes the particles move toward the target distribution, the desired examples, by
a constrained optimal-transport step: each particle heads for the target its exact
optimal-transport assignment gives it, but moves at most a trust-region radius, and
only to a point whose estimated performance stays above the threshold delta.

We follow psclklnk/currot main@4147270 (`deep_sprl/teachers/spl/currot.py` and
`wasserstein_interpolation.py`; docs/BASELINES.md cites each formula and constant),
with two departures (docs/DEVIATIONS.md, "CURROT"), and an option:
- performance is the reference's Nadaraya-Watson regression of episode returns, or, with
  `--teachers.currot-performance critic`, our critic's V(s0, g) (issue 20) against delta
  converted to the value scale (`value_threshold`); the critic overrates goals it has
  not reached, so it is not the default;
- the transport plan is the exact assignment (our auction), not the reference's
  sliced-Wasserstein estimate of it (its icml branch: Sinkhorn at blur 0.01, near exact);
- lengths are expressed as fractions of the goal box (the reference's maze spans 18
  units; ours 28-36), so the trust region and noise scales mean the same everywhere.

The success buffer (`currot_buffer`) keeps the reference's two phases: before delta is
reached it holds the episodes with the best returns (success indicators, the reference's
maze return); after, the successes that best match the target by optimal transport.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
from flax import struct

from d2c_jax.curricula import curriculum, matching, teachers
from d2c_jax.curricula.currot_buffer import (  # noqa: F401  (currot.* as before the split)
    REFERENCE_BOX_WIDTH,
    SuccessBuffer,
    empty_buffer,
    select_entries,
    squared_distances,
    success_samples,
    update_buffer,
)
from d2c_jax.curricula.interface import CurriculumInputs

# Per-episode jitter U(-nu, nu), nu = 1e-3 (ub - lb) (c:71-73, 284).
_JITTER_FRACTION = 1e-3
# The regression's bandwidth h = 0.3 sqrt(eps), the trust region's radius (c:51).
_BANDWIDTH_PER_RADIUS = 0.3
# Queries per Nadaraya-Watson block: a block's distances to the 2N points stay small.
_NW_CHUNK = 100


def value_threshold(delta: float, gamma: float, horizon: int) -> float:
    """delta (a success rate, the reference's maze scale) on our critic's value scale.

    The reference's maze return is the success indicator, so delta = 0.8 asks that 80% of
    the episodes on a goal succeed. Our sparse reward is 1 at every step the goal is
    held, and the critic bootstraps past the time limit, so a goal reached at step t and
    held is worth gamma^t / (1 - gamma). A success anywhere within the horizon H is worth
    at least gamma^H / (1 - gamma); a goal reached with probability p >= delta therefore
    has V >= delta gamma^H / (1 - gamma), the threshold. (gamma = 0.99, H = 100: 29.3 of
    the value range [0, 100].)"""
    return delta * gamma**horizon / (1.0 - gamma)


def transport_targets(particles: jax.Array, targets: jax.Array) -> jax.Array:
    """Each particle's partner in the optimal transport plan between two equal-size
    uniform point sets (an assignment minimising the total squared distance, the W2
    plan): (N, d), (N, d) -> (N, d), targets[sigma(i)]."""
    return targets[matching.auction(squared_distances(particles, targets))]


def nadaraya_watson(queries, points, values, valid, bandwidth: float, k_nearest: int = 10):
    """The reference's performance estimate (u:168-192, nw:197-233): y(x) = sum_j w_j y_j
    with w_j proportional to exp(-|x - c_j|^2 / 2h^2) over the points within 3h of x, or
    over its k nearest points when none is that near. queries (q, d), points (m, d),
    values and valid (m,) -> (q,). (The reference keeps a random half of the neighbours
    when there are many; we keep them all.)"""
    d2 = squared_distances(queries, points)
    d2 = jnp.where(valid[None], d2, jnp.inf)
    near = d2 < (3.0 * bandwidth) ** 2
    k = min(k_nearest, points.shape[0])
    kth = -jax.lax.top_k(-d2, k)[0][:, -1:]  # (q, 1) the k-th smallest distance
    use = jnp.where(near.any(-1, keepdims=True), near, d2 <= kth) & valid[None]
    weights = jax.nn.softmax(jnp.where(use, -d2 / (2.0 * bandwidth**2), -jnp.inf), axis=-1)
    return jnp.sum(jnp.where(use, weights * values[None], 0.0), axis=-1)


# --- the particle step (wasserstein_interpolation.py:19-116) ---------------------------


def ensure_successful(particles, particle_value, samples, sample_value, threshold):
    """Particles below the threshold move to success samples, by the assignment of least
    total squared distance (wi:56-73); only samples above the threshold are eligible when
    there are enough of them. Returns (particles (N, d), reached (N,) bool: the particle
    sits on a point above the threshold)."""
    failing = particle_value < threshold
    eligible = sample_value >= threshold
    restrict = eligible.sum() >= failing.sum()
    dist = squared_distances(particles, samples)
    barred = jnp.where(restrict & ~eligible, jnp.max(dist) + 1.0, 0.0)
    # Rows that do not fail cost the same everywhere: they take what the failing rows
    # leave, so the square problem solves the failing rows' rectangular one.
    assign = matching.auction(jnp.where(failing[:, None], dist + barred[None], 0.0))
    moved = jnp.where(failing[:, None], samples[assign], particles)
    reached = jnp.where(failing, eligible[assign], True)
    return moved, reached


def ball_offsets(key, n: int, d: int) -> jax.Array:
    """n points uniform in the unit d-ball (Gaussian directions, radius U^(1/d)): (n, d)."""
    k_dir, k_rad = jax.random.split(key)
    direction = jax.random.normal(k_dir, (n, d))
    direction = direction / jnp.linalg.norm(direction, axis=-1, keepdims=True)
    return direction * jax.random.uniform(k_rad, (n, 1)) ** (1.0 / d)


def candidates(particles, targets, reached, radius, low, high, key, n: int) -> jax.Array:
    """n candidate moves per particle (wi:19-41): the same unit-ball offsets for all,
    reflected into the half-ball facing the target for particles that reached the
    threshold, scaled by min(radius, distance to target), clipped. -> (N, n, d)."""
    offsets = ball_offsets(key, n, particles.shape[-1])  # (n, d)
    step = targets - particles  # (N, d)
    length2 = jnp.maximum(jnp.sum(step**2, axis=-1, keepdims=True), 1e-12)  # (N, 1)
    along = offsets @ step.T  # (n, N)
    backward = (along < 0) & reached[None]
    reflected = offsets[:, None] - 2.0 * (along / length2.T)[..., None] * step[None]
    moves = jnp.where(backward[..., None], reflected, offsets[:, None])  # (n, N, d)
    scale = jnp.minimum(radius, jnp.sqrt(length2))  # (N, 1)
    return jnp.clip(particles[:, None] + scale[:, None] * moves.swapaxes(0, 1), low, high)


def choose_moves(cands, cand_value, targets, threshold) -> tuple[jax.Array, jax.Array]:
    """Per particle, the candidate above the threshold nearest its target, else the
    best-valued one (wi:85-94). (N, n, d), (N, n), (N, d) -> ((N, d), (N,) feasible)."""
    feasible = cand_value > threshold
    dist = jnp.sum((cands - targets[:, None]) ** 2, axis=-1)
    any_feasible = feasible.any(-1)
    pick = jnp.where(
        any_feasible,
        jnp.argmin(jnp.where(feasible, dist, jnp.inf), axis=-1),
        jnp.argmax(cand_value, axis=-1),
    )
    return jnp.take_along_axis(cands, pick[:, None, None], axis=1)[:, 0], any_feasible


# --- the teacher ---------------------------------------------------------------------------


@struct.dataclass
class CurrotState:
    """The particles, the success buffer and the episodes since the last update."""

    particles: jax.Array  # (N, d)
    buffer: SuccessBuffer
    episode_goals: jax.Array  # (E, d) goals of the episodes since the last update
    episode_returns: jax.Array  # (E,) float32 their success indicators
    episode_count: jax.Array  # () int32 episodes held
    updates: jax.Array  # () int32 particle updates done
    threshold_reached: jax.Array  # () bool the particles' mean performance once met delta
    fail_goals: jax.Array  # (N, d) the last N episodes that did not enter the buffer
    fail_returns: jax.Array  # (N,) float32 their returns (c:38-42); -inf: empty


class CurrotTeacher(teachers.Teacher):
    """CURROT's particles as a goal teacher (see the module docstring).

    `currot_performance` picks the performance estimate: "critic", V(s0, g) against
    `value_threshold(delta)`; or "returns", the reference's Nadaraya-Watson regression of
    the success and failure buffers' episode returns against delta itself."""

    def __init__(self, cfg, env, classifier_net, uses_goal_value: bool = False):
        super().__init__(cfg, env, classifier_net, uses_goal_value)
        t = cfg.teachers
        self.low = jnp.asarray(env.goal_low, jnp.float32)
        self.high = jnp.asarray(env.goal_high, jnp.float32)
        diagonal = float(jnp.linalg.norm(self.high - self.low))
        self.radius = t.currot_trust_region * diagonal
        self.bandwidth = _BANDWIDTH_PER_RADIUS * self.radius
        self.uses_critic = t.currot_performance == "critic"
        self.needs_value = self.needs_start_obs = self.uses_critic
        self.threshold = (
            value_threshold(t.currot_delta, cfg.sac.gamma, env.horizon)
            if self.uses_critic
            else t.currot_delta
        )
        # Whole iterations of episodes per update: at least currot_episodes_per_update.
        per_iteration = cfg.num_envs
        self.episodes_per_update = (
            math.ceil(t.currot_episodes_per_update / per_iteration) * per_iteration
        )

    def init(self, key) -> CurrotState:
        t, d = self.cfg.teachers, self.env.goal_dim
        return CurrotState(
            particles=self.env.sample_uniform_goals(key, t.currot_particles),  # me:179-180
            buffer=empty_buffer(t.currot_particles, d),
            episode_goals=jnp.zeros((self.episodes_per_update, d), jnp.float32),
            episode_returns=jnp.zeros((self.episodes_per_update,), jnp.float32),
            episode_count=jnp.zeros((), jnp.int32),
            updates=jnp.zeros((), jnp.int32),
            threshold_reached=jnp.zeros((), bool),
            fail_goals=jnp.zeros((t.currot_particles, d), jnp.float32),
            fail_returns=jnp.full((t.currot_particles,), -jnp.inf, jnp.float32),
        )

    def propose(self, state: CurrotState, inputs: CurriculumInputs, key):
        k = self.cfg.curriculum.n_slots
        k_pick, k_jitter, k_metrics = jax.random.split(key, 3)
        picks = jax.random.randint(k_pick, (k,), 0, state.particles.shape[0])
        nu = _JITTER_FRACTION * (self.high - self.low)
        jitter = jax.random.uniform(k_jitter, (k, self.env.goal_dim), minval=-nu, maxval=nu)
        goals = jnp.clip(state.particles[picks] + jitter, self.low, self.high)
        return goals, self.metrics(goals, k_metrics), state

    def performance(self, state: CurrotState, buffer: SuccessBuffer, inputs: CurriculumInputs):
        """The estimate, goals (..., d) -> (...), on the scale of `self.threshold`."""
        if self.uses_critic:

            def critic(goals):
                obs = jnp.broadcast_to(inputs.start_obs, goals.shape[:-1] + inputs.start_obs.shape)
                return inputs.value_fn(obs, goals)

            return critic
        points = jnp.concatenate([buffer.goals, state.fail_goals])
        values = jnp.concatenate([buffer.returns, state.fail_returns])
        valid = jnp.isfinite(values)

        def regression(goals):
            flat = goals.reshape(-1, goals.shape[-1])
            # Blocks of queries: (chunk, 2N) distances at a time, not (N n, 2N).
            chunk = min(flat.shape[0], _NW_CHUNK)
            pad = -flat.shape[0] % chunk
            blocks = jnp.pad(flat, ((0, pad), (0, 0))).reshape(-1, chunk, flat.shape[-1])
            out = jax.lax.map(
                lambda q: nadaraya_watson(q, points, values, valid, self.bandwidth), blocks
            )
            return out.reshape(-1)[: flat.shape[0]].reshape(goals.shape[:-1])

        return regression

    def observe(self, state: CurrotState, episodes, inputs: CurriculumInputs):
        goals = episodes.goal[:, 0]
        successes = episodes.success.any(axis=1).astype(jnp.float32)  # the maze's return
        at = state.episode_count + jnp.arange(goals.shape[0])
        state = state.replace(
            episode_goals=state.episode_goals.at[at].set(goals, mode="drop"),
            episode_returns=state.episode_returns.at[at].set(successes, mode="drop"),
            episode_count=state.episode_count + goals.shape[0],
        )
        due = state.episode_count >= self.episodes_per_update
        state = jax.lax.cond(due, lambda s: self.update(s, inputs), lambda s: s, state)
        buf = state.buffer
        held = jnp.isfinite(buf.returns)  # the entries in [0, count) but the initial dummy
        performance = self.performance(state, buf, inputs)(state.particles)
        return state, {
            # 1: the particles sit at delta on average.
            "currot/performance_ratio": performance.mean() / self.threshold,
            "currot/buffer_return": jnp.where(held, buf.returns, 0.0).sum()
            / jnp.maximum(held.sum(), 1),
            "currot/delta_reached": buf.delta_reached.astype(jnp.float32),
            "currot/updates": state.updates.astype(jnp.float32),
        }

    def update(self, state: CurrotState, inputs: CurriculumInputs) -> CurrotState:
        """One CURROT step on the held episodes (c:32-69 with wi:75-116)."""
        t = self.cfg.teachers
        n = t.currot_particles
        k_target, k_samples, k_plan, k_cands = jax.random.split(inputs.key, 4)
        buffer, entered = update_buffer(
            state.buffer, state.episode_goals, state.episode_returns,
            curriculum.goal_slots(self.env, n, k_target), t.currot_delta, state.updates,
        )  # fmt: skip
        if not self.uses_critic:  # the failures feed the regression once delta was met
            state = record_failures(state, ~entered & state.threshold_reached)
        performance = self.performance(state, buffer, inputs)
        particle_perf = performance(state.particles)
        samples = success_samples(buffer, n, t.currot_delta, self.low, self.high, k_samples)
        particles, reached = ensure_successful(
            state.particles, particle_perf, samples, performance(samples), self.threshold
        )
        targets = transport_targets(particles, curriculum.goal_slots(self.env, n, k_plan))
        cands = candidates(
            particles, targets, reached, self.radius, self.low, self.high, k_cands,
            t.currot_candidates,
        )  # fmt: skip
        particles, _ = choose_moves(cands, performance(cands), targets, self.threshold)
        return state.replace(
            particles=particles,
            buffer=buffer,
            episode_count=jnp.zeros((), jnp.int32),
            updates=state.updates + 1,
            threshold_reached=state.threshold_reached | (particle_perf.mean() >= self.threshold),
        )


def record_failures(state: CurrotState, failed: jax.Array) -> CurrotState:
    """The fail buffer (a FIFO of the last N, c:38-42) after this update's episodes whose
    `failed` (E,) is set, in episode order."""
    n = state.fail_returns.shape[0]
    order = jnp.argsort(~failed, stable=True)  # the failures first, in order
    count = failed.sum()
    goals = jnp.concatenate([state.fail_goals, state.episode_goals[order]])
    returns = jnp.concatenate([state.fail_returns, state.episode_returns[order]])
    # The last n of the old entries followed by the `count` new ones.
    take = jnp.arange(n) + count
    return state.replace(fail_goals=goals[take], fail_returns=returns[take])
