"""Episode-structured circular replay buffer as a pure pytree (SPEC §2 step 3, §4).

The buffer stores whole episodes in `n_slots = capacity // H` slots; inserting a batch of
episodes writes them at consecutive slots from a write pointer, modulo `n_slots`, so the
oldest episodes are overwritten first. Every stored episode is complete, so a transition
(episode e, step t in [0, H)) is valid iff slot e has been written; `obs[e, t + 1]` is
always the same episode's next observation and HER's future steps t' in [t + 1, H] stay
inside the episode.

Memory per transition (float32): 4 * ((H + 1)/H * (obs_dim + goal_dim) + action_dim +
goal_dim) bytes; point mazes (6, 2, 2, H = 100): ~48 bytes, so 3e6 transitions ~145 MB;
Ant (29, 8, 2, H = 300): ~165 bytes, ~0.5 GB. Everything is jittable with fixed shapes.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from flax import struct

from d2c_jax.config import ReplayConfig


@struct.dataclass
class ReplayState:
    """Stored episodes plus the write pointer (leading seed axis when vmapped)."""

    obs: jax.Array  # (n_slots, H + 1, obs_dim)
    achieved_goal: jax.Array  # (n_slots, H + 1, goal_dim) phi(s_t)
    action: jax.Array  # (n_slots, H, action_dim)
    goal: jax.Array  # (n_slots, H, goal_dim) the goal active when action t was taken
    walk_start: jax.Array  # (n_slots,) int32 first random-walk step (H: the goal never reached)
    ptr: jax.Array  # () int32 next slot to write
    size: jax.Array  # () int32 slots holding an episode (<= n_slots)

    @property
    def n_slots(self) -> int:
        """Capacity in episodes (static)."""
        return self.obs.shape[-3]

    @property
    def horizon(self) -> int:
        """Episode length H (static)."""
        return self.action.shape[-2]


class Transition(NamedTuple):
    """Sampled transitions with their location in the buffer."""

    obs: jax.Array  # (B, obs_dim) s_t
    action: jax.Array  # (B, action_dim) a_t
    next_obs: jax.Array  # (B, obs_dim) s_{t+1}
    next_achieved_goal: jax.Array  # (B, goal_dim) phi(s_{t+1})
    goal: jax.Array  # (B, goal_dim) the goal active at step t
    episode: jax.Array  # (B,) int32 slot index
    step: jax.Array  # (B,) int32 t in [0, H)


def init_replay(
    cfg: ReplayConfig, obs_dim: int, action_dim: int, goal_dim: int, horizon: int
) -> ReplayState:
    """An empty buffer of `cfg.capacity // horizon` episode slots.

    Raises:
      ValueError: if the capacity holds less than one episode.
    """
    n_slots = cfg.capacity // horizon
    if n_slots < 1:
        raise ValueError(f"replay capacity {cfg.capacity} < one episode of {horizon} steps")
    zeros = lambda *shape: jnp.zeros((n_slots, *shape), jnp.float32)  # noqa: E731
    return ReplayState(
        obs=zeros(horizon + 1, obs_dim),
        achieved_goal=zeros(horizon + 1, goal_dim),
        action=zeros(horizon, action_dim),
        goal=zeros(horizon, goal_dim),
        walk_start=jnp.full((n_slots,), horizon, jnp.int32),
        ptr=jnp.zeros((), jnp.int32),
        size=jnp.zeros((), jnp.int32),
    )


def insert_episodes(state: ReplayState, episodes) -> ReplayState:
    """Writes n whole episodes at slots ptr, ptr + 1, ... (mod n_slots).

    Args:
      state: the buffer.
      episodes: any record with fields obs (n, H + 1, obs_dim), achieved_goal
        (n, H + 1, goal_dim), action (n, H, action_dim), goal (n, H, goal_dim), and
        optionally walk_start (n,) int32 (`rollout.Episodes`; without it, every step
        counts as the curriculum phase); other fields are ignored.
    Returns:
      The buffer with the n oldest slots (or the empty ones) overwritten.
    Raises:
      ValueError: at trace time, if n > n_slots (a scatter with repeated slots).
    """
    n = episodes.obs.shape[0]
    if n > state.n_slots:
        raise ValueError(f"cannot insert {n} episodes into a buffer of {state.n_slots} slots")
    slots = (state.ptr + jnp.arange(n, dtype=jnp.int32)) % state.n_slots  # (n,) distinct

    def write(buf, new):
        return buf.at[slots].set(new.astype(buf.dtype), unique_indices=True)

    return state.replace(
        obs=write(state.obs, episodes.obs),
        achieved_goal=write(state.achieved_goal, episodes.achieved_goal),
        action=write(state.action, episodes.action),
        goal=write(state.goal, episodes.goal),
        walk_start=write(state.walk_start, _walk_start(episodes, state.horizon)),
        ptr=(state.ptr + n) % state.n_slots,
        size=jnp.minimum(state.size + n, state.n_slots),
    )


def _walk_start(episodes, horizon: int) -> jax.Array:
    """(n,) int32 first random-walk step of each episode; H when the record has none."""
    walk_start = getattr(episodes, "walk_start", None)
    if walk_start is None:
        return jnp.full((episodes.obs.shape[0],), horizon, jnp.int32)
    return walk_start


def _sample_slots(state: ReplayState, n: int, key: jax.Array) -> jax.Array:
    """(n,) int32 slots uniform over the filled ones.

    Slots fill from 0 upwards and are never emptied, so the filled ones are [0, size).
    An empty buffer yields slot 0 (zeros).
    """
    return jax.random.randint(key, (n,), 0, jnp.maximum(state.size, 1))


def _sample_in_ranges(
    state: ReplayState, lo: jax.Array, hi: jax.Array, n: int, key: jax.Array
) -> tuple[jax.Array, jax.Array, jax.Array]:
    """n (slot, step) pairs uniform over the steps t in [lo_e, hi_e) of the filled slots e.

    Inverse-CDF sampling over the per-slot counts: every admissible step is equally likely,
    whatever its episode.

    Args:
      lo, hi: (n_slots,) int32 step ranges per slot.
    Returns:
      slots (n,), steps (n,) int32, and () bool: some step is admissible (else garbage).
    """
    filled = jnp.arange(state.n_slots) < state.size
    count = jnp.where(filled, jnp.maximum(hi - lo, 0), 0)  # (n_slots,)
    cum = jnp.cumsum(count)
    u = jax.random.randint(key, (n,), 0, jnp.maximum(cum[-1], 1))
    ep = jnp.minimum(jnp.searchsorted(cum, u, side="right"), state.n_slots - 1)
    t = lo[ep] + u - (cum[ep] - count[ep])
    return ep.astype(jnp.int32), t.astype(jnp.int32), cum[-1] > 0


def _uniform_steps(state: ReplayState, n: int, key: jax.Array, n_steps: int):
    """(n,) slots uniform over the filled ones and (n,) steps uniform in [0, n_steps)."""
    key_ep, key_t = jax.random.split(key)
    ep = _sample_slots(state, n, key_ep)
    return ep, jax.random.randint(key_t, (n,), 0, n_steps)


def _transitions(state: ReplayState, ep: jax.Array, t: jax.Array) -> Transition:
    return Transition(
        obs=state.obs[ep, t],
        action=state.action[ep, t],
        next_obs=state.obs[ep, t + 1],
        next_achieved_goal=state.achieved_goal[ep, t + 1],
        goal=state.goal[ep, t],
        episode=ep,
        step=t,
    )


def sample_phase_steps(state: ReplayState, n: int, key: jax.Array, walk: bool):
    """(n,) slots and steps uniform over the transitions of one phase of the episodes.

    Curriculum phase: t < walk_start (the goal was the curriculum goal); random walk:
    t >= walk_start (post-success goals). With no transition of the phase stored yet,
    falls back to all transitions.
    """
    key_phase, key_any = jax.random.split(key)
    zeros = jnp.zeros_like(state.walk_start)
    lo, hi = (state.walk_start, zeros + state.horizon) if walk else (zeros, state.walk_start)
    ep, t, ok = _sample_in_ranges(state, lo, hi, n, key_phase)
    ep_any, t_any = _uniform_steps(state, n, key_any, state.horizon)
    return jnp.where(ok, ep, ep_any), jnp.where(ok, t, t_any)


def sample(
    state: ReplayState, batch_size: int, key: jax.Array, walk_fraction: float = 0.0
) -> Transition:
    """Transitions for SAC: uniform over all stored ones, or split by phase.

    With walk_fraction = 0 every transition is equally likely (all episodes have length
    H). With walk_fraction > 0 (OUTPACE's two buffers, issue 10 rule 3), round(walk_fraction
    * B) rows are uniform over the random-walk transitions (after the episode's goal was
    first reached) and the rest uniform over the curriculum-phase transitions.

    Args:
      state: the buffer (non-empty).
      batch_size: B.
      key: PRNG key.
      walk_fraction: static share of the batch from the random-walk phase.
    Returns:
      Transition with leading axis B.
    """
    n_walk = round(walk_fraction * batch_size)
    if n_walk == 0:
        return _transitions(state, *_uniform_steps(state, batch_size, key, state.horizon))
    key_main, key_walk = jax.random.split(key)
    ep_main, t_main = sample_phase_steps(state, batch_size - n_walk, key_main, walk=False)
    ep_walk, t_walk = sample_phase_steps(state, n_walk, key_walk, walk=True)
    ep = jnp.concatenate([ep_main, ep_walk])
    return _transitions(state, ep, jnp.concatenate([t_main, t_walk]))


def sample_achieved_goals(
    state: ReplayState, n: int, key: jax.Array, curriculum_phase_only: bool = False
) -> jax.Array:
    """Achieved goals phi(s) of n states uniform over stored ones: (n, goal_dim).

    Every state s_0..s_H of a stored episode counts (the classifier's negatives, Eq. 5),
    or, with `curriculum_phase_only`, the states s_0..s_{walk_start} the agent reached
    while pursuing its curriculum goal (OUTPACE: places only random walks reached stay
    "unvisited" to the classifier, so the curriculum follows them; issue 10 rule 3).
    """
    if not curriculum_phase_only:
        ep, t = _uniform_steps(state, n, key, state.horizon + 1)
        return state.achieved_goal[ep, t]
    lo = jnp.zeros_like(state.walk_start)
    ep, t, _ = _sample_in_ranges(state, lo, state.walk_start + 1, n, key)
    return state.achieved_goal[ep, t]


def hold_after(trajectories: jax.Array, stop: jax.Array) -> jax.Array:
    """Each trajectory with its states after step `stop` replaced by the state at `stop`:
    (P, T, ...), (P,) int -> (P, T, ...); row p, step t reads step min(t, stop_p).

    With stop = `walk_start` a trajectory keeps s_0..s_w, the states reached while pursuing
    the curriculum goal up to the one that reached it (`CurriculumConfig.pool_phase`):
    a minimum over steps, or the first-to-last move, then sees only those states.
    """
    rows = jnp.arange(trajectories.shape[0])[:, None]  # (P, 1)
    held = jnp.minimum(jnp.arange(trajectories.shape[1])[None, :], stop[:, None])  # (P, T)
    return trajectories[rows, held]


def recent_episode_slots(state: ReplayState, p: int) -> tuple[jax.Array, jax.Array]:
    """Buffer slots (p,) int32 of the p most recent episodes (SPEC §5 pool), most recent
    first, and valid (p,) bool (false beyond the episodes stored so far, whose contents
    are meaningless). `state.achieved_goal[slots]` are their trajectories.

    Raises:
      ValueError: if p > n_slots.
    """
    if p > state.n_slots:
        raise ValueError(f"pool of {p} episodes exceeds the buffer's {state.n_slots} slots")
    back = jnp.arange(p, dtype=jnp.int32)
    return (state.ptr - 1 - back) % state.n_slots, back < state.size


def archived_episode_slots(
    state: ReplayState, a: int, key: jax.Array, log_weights: jax.Array | None = None
) -> tuple[jax.Array, jax.Array]:
    """Buffer slots (a,) of `a` distinct episodes drawn from the stored ones, and valid
    (a,) bool (false while fewer than `a` episodes are stored).

    The curriculum's long memory (issue 10 rule 5; HGG keeps a pool of 1000 trajectories):
    a frontier state reached once, long ago, stays a matching candidate.

    Args:
      log_weights: (n_slots,) unnormalised log-probabilities of the slots; None: uniform.
    Raises:
      ValueError: if a > n_slots.
    """
    if a > state.n_slots:
        raise ValueError(f"archive of {a} episodes exceeds the buffer's {state.n_slots} slots")
    filled = jnp.arange(state.n_slots) < state.size
    # Gumbel top-k: a sample without replacement among the filled slots, each drawn with
    # probability proportional to exp(log_weights) (uniform without them).
    gumbel = jax.random.gumbel(key, (state.n_slots,))
    if log_weights is not None:
        gumbel = gumbel + log_weights
    scores = jnp.where(filled, gumbel, -jnp.inf)
    _, slots = jax.lax.top_k(scores, a)
    return slots, filled[slots]
