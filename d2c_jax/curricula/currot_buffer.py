"""CURROT's success buffer (psclklnk/currot `deep_sprl/teachers/spl/currot.py`, cited
as c:LINE; docs/BASELINES.md), the memory `currot.CurrotTeacher` samples its particles'
destinations from.

Two phases, as the reference: before delta is reached it holds the episodes with the
best returns; after, the successes that best match the target by optimal transport.
Pure and jittable with fixed shapes; `d2c_jax.curricula.currot` re-exports every name.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

from d2c_jax.curricula import matching

# The reference's maze spans [-9, 9]^2: its trust region sqrt(eps) = sqrt(1.5) is this
# fraction of the goal box's diagonal (c:21, me:49); `TeachersConfig.currot_trust_region`.
REFERENCE_BOX_WIDTH = 18.0
# The least std of a success sample, 0.005 eps in the reference's units (c:90-91).
_MIN_STD_FRACTION = 0.005 * 1.5 / REFERENCE_BOX_WIDTH
# A failed sample's std reaches (ub - lb) / 4 (c:129-130).
_MAX_STD_FRACTION = 0.25
# Out-of-bounds success samples are redrawn up to this many times, then clipped (c:157-168).
_NOISE_TRIES = 10


def squared_distances(a: jax.Array, b: jax.Array) -> jax.Array:
    """||a_i - b_j||^2: (n, d), (m, d) -> (n, m)."""
    return jnp.sum((a[:, None, :] - b[None, :, :]) ** 2, axis=-1)


# --- the success buffer (c:189-278) ---------------------------------------------------


@struct.dataclass
class SuccessBuffer:
    """Up to N (goal, return) pairs, ascending by return in [0, count)."""

    goals: jax.Array  # (N, d)
    returns: jax.Array  # (N,) float32; -inf beyond count
    stamps: jax.Array  # (N,) int32 the update that inserted each entry
    count: jax.Array  # () int32
    delta_reached: jax.Array  # () bool more than half the buffer met delta (phase B)
    min_return: jax.Array  # () float32 the first batch's least return (read_update's scale)


def empty_buffer(n: int, d: int) -> SuccessBuffer:
    """The reference's initial buffer: one dummy entry of return -inf (c:95-96)."""
    return SuccessBuffer(
        goals=jnp.zeros((n, d), jnp.float32),
        returns=jnp.full((n,), -jnp.inf, jnp.float32),
        stamps=jnp.zeros((n,), jnp.int32),
        count=jnp.ones((), jnp.int32),
        delta_reached=jnp.zeros((), bool),
        min_return=jnp.full((), jnp.inf, jnp.float32),
    )


def select_entries(goals, returns, stamps, keep, priority, n: int, buf: SuccessBuffer):
    """(The buffer holding the n highest-`priority` entries among `keep`, stored ascending
    by return; (m - n,) bool which of the rows after the first n, the new episodes, are
    in it). goals (m, d), returns, stamps, keep, priority (m,), m >= n."""
    top = jnp.lexsort((-priority, ~keep))[:n]  # kept entries first, best priority first
    valid = keep[top]
    order = top[jnp.lexsort((returns[top], ~valid))]  # valid first, ascending return
    valid = keep[order]
    entered = jnp.zeros((goals.shape[0],), bool).at[order].max(valid)[n:]
    buf = buf.replace(
        goals=goals[order],
        returns=jnp.where(valid, returns[order], -jnp.inf),
        stamps=stamps[order],
        count=valid.sum().astype(jnp.int32),
    )
    return buf, entered


def update_buffer(buf: SuccessBuffer, goals, returns, targets, delta: float, stamp):
    """(The buffer after a batch of episodes (goals (m, d), returns (m,)), (m,) bool which
    of them entered it); `targets` (N, d) are fresh target samples for phase B's
    transport selection.

    Phase A (delta not reached, c:194-229): episodes at or above the buffer's median
    enter, as many of the lowest entries leave (at most half the buffer plus one), the
    best N stay; delta is reached once the median before the update exceeds it.
    Phase B (c:231-278): successes (return >= delta) enter. When the buffer is full and
    holds only successes, the N entries of buffer and successes that best transport onto
    the targets stay; otherwise the new successes replace the lowest-return entries and
    the oldest entries leave past N."""
    n, m = buf.returns.shape[0], returns.shape[0]
    slot = jnp.arange(n)
    valid = slot < buf.count
    all_goals = jnp.concatenate([buf.goals, goals])
    all_returns = jnp.concatenate([buf.returns, returns])
    all_stamps = jnp.concatenate([buf.stamps, jnp.full((m,), stamp, jnp.int32)])
    first = jnp.isinf(buf.min_return)  # the first batch sets the scale (c:113-114)
    buf = buf.replace(min_return=jnp.where(first, returns.min(), buf.min_return))

    def phase_a(buf: SuccessBuffer) -> tuple[SuccessBuffer, jax.Array]:
        median = buf.returns[buf.count // 2]
        accept = returns >= median
        dropped = jnp.minimum(buf.count // 2 + 1, accept.sum())
        keep = jnp.concatenate([valid & (slot >= dropped), accept])
        out, entered = select_entries(all_goals, all_returns, all_stamps, keep, all_returns, n, buf)
        return out.replace(delta_reached=median > delta), entered

    def phase_b(buf: SuccessBuffer) -> tuple[SuccessBuffer, jax.Array]:
        success = returns >= delta
        low = valid & (buf.returns < delta)
        sources_ok = jnp.concatenate([valid, success])

        def by_transport(_):
            # Targets bid for sources; sources other than buffer and successes are barred.
            dist = squared_distances(targets, all_goals)
            barred = jnp.max(dist) + 1.0
            kept_source = matching.auction(jnp.where(sources_ok[None], dist, barred))
            keep = jnp.zeros((n + m,), bool).at[kept_source].set(True) & sources_ok
            return select_entries(all_goals, all_returns, all_stamps, keep, all_returns, n, buf)

        def by_replacement(_):
            # The lowest entries are the first ones; min(#successes, #low) of them leave.
            removed = slot < jnp.minimum(success.sum(), low.sum())
            keep = jnp.concatenate([valid & ~removed, success])
            return select_entries(all_goals, all_returns, all_stamps, keep, all_stamps, n, buf)

        use_transport = success.any() & ~low.any() & (buf.count >= n)
        return jax.lax.cond(use_transport, by_transport, by_replacement, None)

    return jax.lax.cond(buf.delta_reached, phase_b, phase_a, buf)


def success_samples(buf: SuccessBuffer, n: int, delta: float, low, high, key) -> jax.Array:
    """N noisy samples around the buffer's entries (read_update, c:127-168): (n, d).

    Phase A draws from the upper half of the buffer with p_j proportional to R_j minus the
    return just below that half (uniformly when all are equal); phase B takes every entry
    and fills up to n uniformly. Entry j's noise std is the floor plus (delta - R_j)^+ /
    (delta - min_return) of a quarter of the box: failures spread, successes stay put."""
    k_pick, k_fill, k_noise = jax.random.split(key, 3)
    size = buf.returns.shape[0]
    slot = jnp.arange(size)
    half = buf.count // 2
    upper = (slot >= half) & (slot < buf.count)
    weight = jnp.where(upper, buf.returns - buf.returns[jnp.maximum(half - 1, 0)], 0.0)
    weight = jnp.where(weight.sum() > 0, weight, upper.astype(jnp.float32))
    phase_a = jax.random.choice(k_pick, size, (n,), p=weight / weight.sum())
    fill = jax.random.randint(k_fill, (n,), 0, jnp.maximum(buf.count, 1))
    rows = jnp.arange(n)
    phase_b = jnp.where(rows < buf.count, jnp.minimum(rows, size - 1), fill)
    index = jnp.where(buf.delta_reached, phase_b, phase_a)

    width = high - low
    shortfall = jnp.clip(delta - buf.returns[index], 0.0, None)
    scale = jnp.maximum(delta - buf.min_return, 1e-6)
    std = (_MIN_STD_FRACTION + shortfall[:, None] / scale * _MAX_STD_FRACTION) * width
    centres = buf.goals[index]
    tries = centres + std * jax.random.normal(k_noise, (_NOISE_TRIES,) + centres.shape)
    inside = jnp.all((tries >= low) & (tries <= high), axis=-1)  # (tries, n)
    first = jnp.where(inside.any(0), jnp.argmax(inside, axis=0), _NOISE_TRIES - 1)
    return jnp.clip(tries[first, rows], low, high)
