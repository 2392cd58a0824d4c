"""Rectangular assignment by the forward auction with ε-scaling (SPEC §5a).

The curriculum (SPEC §5) assigns K goal slots to K distinct trajectories out of a
pool of P ≥ K by minimising the total cost. This module solves that problem inside
jit with fixed shapes: Bertsekas' forward auction (Bertsekas 1988, "The auction
algorithm: a distributed relaxation method for the assignment problem") with
ε-scaling, on benefits = −cost, in one `lax.while_loop`.

Rectangular problems (K < P). Plain forward ε-scaling is not optimal there: prices
raised in an early phase stay on columns that end unassigned. We solve the square
P×P problem padded with P − K dummy rows of constant cost, so that every column is
as good as any other to a dummy (Bertsekas & Castañon 1992, "A forward/reverse
auction algorithm for asymmetric assignment problems", §1). The dummies are
interchangeable, so they are kept as one block: the set of columns they hold, all at
one common price. Where each dummy would bid one at a time for the cheapest column
(one column per round, a price war in steps of ε), the block takes the u cheapest
free or real-held columns in one vectorised step and lifts all its prices to one
level that keeps every dummy ε-happy (see `_dummy_step`).

Optimality. At termination every row is ε-happy (ε-complementary slackness), and
the columns the real rows leave unused are priced within ε of the lowest price.
Then the real rows' total cost is within min(2K, P)·ε of the optimum (the dummy
rows' slack plus the real rows'; Bertsekas 1998, "Network Optimization", Prop. 7.1
for the n·ε bound), so the last phase runs at ε = eps_final·K / min(2K, P).

Parallel (Jacobi) bidding: every unassigned real row bids at once, each column takes
its best bid. That is one (K, P) reduction per round, which is what makes the loop
fast on vectorised hardware, and the reason not to bid one row at a time.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from d2c_jax.config import CurriculumConfig

# ε-scaling schedule (Bertsekas 1988, §4): the first phase runs at this fraction of
# the cost range, and each later phase divides ε by _EPS_DIVISOR. Prices are kept
# between phases, which is what makes the late, small-ε phases short.
_EPS_START = 0.2
_EPS_DIVISOR = 6.0
# Safety factor on the final ε for float32 rounding in the ε-CS bound.
_EPS_MARGIN = 0.9
# Smallest usable ε relative to the cost range: prices stay within about 3 ranges of
# each other (re-centred every phase), so a bid increment must exceed their float ulp.
_EPS_FLOOR_ULPS = 16.0
# Bidders per round for large K (see `_bid_round`).
_MAX_BIDDERS = 64
_BIDDER_FRACTION = 8
# Default cap on bidding rounds over all phases: far above what any test problem uses.
# The curriculum config's default, so that the number is written once.
_DEFAULT_MAX_ITERS = CurriculumConfig.auction_max_iters


def _bidders(k: int) -> int:
    """Rows that may bid in one round (static): all of them for small K."""
    return k if k <= _MAX_BIDDERS else max(_MAX_BIDDERS, k // _BIDDER_FRACTION)


class AuctionResult(NamedTuple):
    """Outcome of `auction_solve`."""

    assignment: jax.Array  # (K,) int32, distinct columns in [0, P)
    prices: jax.Array  # (P,) column prices, in cost units (the dual variables)
    converged: jax.Array  # () bool, False when max_iters stopped the auction
    iterations: jax.Array  # () int32, bidding rounds over all ε phases


class _Loop(NamedTuple):
    """Carry of the auction's while loop; costs normalised to a range of 1."""

    assign: jax.Array  # (K,) int32, column of each real row, -1 if unassigned
    owner: jax.Array  # (P,) int32, row holding each column: [0, K) real, K dummy, K+1 free
    prices: jax.Array  # (P,) float
    level: jax.Array  # () float, the common price of the dummy-held columns
    eps: jax.Array  # () float, ε of the current phase
    it: jax.Array  # () int32


def _top2(values: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Best column, best value and second-best value of each row of (K, P) values.

    Written as plain max/min reductions: XLA's CPU argmax (a variadic reduce) is
    about 10x slower than this on a (256, 512) matrix.
    """
    cols = jnp.arange(values.shape[1], dtype=values.dtype)
    v1 = jnp.max(values, axis=1)
    is_best = values == v1[:, None]
    # Lowest index among ties; a tie means the second-best value equals the best.
    best = jnp.min(jnp.where(is_best, cols, jnp.inf), axis=1).astype(jnp.int32)
    ties = jnp.sum(is_best.astype(values.dtype), axis=1)
    v2 = jnp.max(jnp.where(is_best, -jnp.inf, values), axis=1)
    # One column (or all tied): no competitor, so the bid is the minimal increment ε.
    return best, v1, jnp.where((ties > 1) | jnp.isneginf(v2), v1, v2)


def _new_phase(benefit: jax.Array, s: _Loop, eps_target: jax.Array) -> _Loop:
    """Starts the next ε phase from a complete assignment of the current one.

    Prices are kept (that is the point of ε-scaling) but shifted so the lowest is 0
    (the square problem is invariant to a common shift; this bounds their float
    magnitude), with the dummy block lowered to that lowest price so dummies are
    exactly happy. Real rows that are not ε-happy at the new ε are unassigned.
    """
    k = benefit.shape[0]
    low = jnp.min(s.prices)
    prices = jnp.where(s.owner == k, low, s.prices) - low
    eps = jnp.maximum(s.eps / _EPS_DIVISOR, eps_target)
    values = benefit - prices
    held = jnp.take_along_axis(values, jnp.maximum(s.assign, 0)[:, None], axis=1)[:, 0]
    unhappy = held < jnp.max(values, axis=1) - eps
    owner = jnp.where(unhappy[jnp.clip(s.owner, 0, k - 1)] & (s.owner < k), k + 1, s.owner)
    assign = jnp.where(unhappy, -1, s.assign)
    return s._replace(assign=assign, owner=owner, prices=prices, level=jnp.zeros_like(low), eps=eps)


def _bid_round(benefit: jax.Array, s: _Loop) -> _Loop:
    """One Jacobi round: up to `_bidders(K)` unassigned real rows bid at once.

    A bid raises the column's price to the level at which the second-best column is
    equally good, plus ε (Bertsekas 1988, bidding phase), so the winner is ε-happy
    and every accepted bid raises a price by at least ε. Any nonempty subset of the
    unassigned rows may bid in a round; capping it at B rows makes a round cost
    O(B·P) instead of O(K·P), and after the first rounds of a phase few rows bid.
    """
    k, p = benefit.shape
    n_bid = _bidders(k)
    if n_bid < k:
        rows = jnp.nonzero(s.assign < 0, size=n_bid, fill_value=k)[0].astype(jnp.int32)
        gain = benefit[jnp.minimum(rows, k - 1)]  # (B, P)
        bidding = rows < k
    else:
        rows = jnp.arange(k, dtype=jnp.int32)
        gain = benefit
        bidding = s.assign < 0
    best, _, v2 = _top2(gain - s.prices)
    bid = jnp.take_along_axis(gain, best[:, None], axis=1)[:, 0] - v2 + s.eps
    target = jnp.where(bidding, best, p)  # p: dropped by the scatters below
    top_bid = jnp.full((p,), -jnp.inf, bid.dtype).at[target].max(bid, mode="drop")
    is_top = bidding & (bid >= top_bid[best])
    winner = jnp.full((p,), k, jnp.int32).at[jnp.where(is_top, best, p)].min(rows, mode="drop")
    won = winner < k
    # Rows outbid lose their column; then the winners take theirs.
    outbid = jnp.where(won & (s.owner < k), s.owner, k)
    assign = s.assign.at[outbid].set(-1, mode="drop")
    assign = assign.at[jnp.where(won, winner, k)].set(jnp.arange(p, dtype=jnp.int32), mode="drop")
    return s._replace(
        assign=assign,
        owner=jnp.where(won, winner, s.owner),
        prices=jnp.where(won, top_bid, s.prices),
    )


def _dummy_step(s: _Loop, k: int) -> _Loop:
    """All u unassigned dummy rows bid at once, as a block.

    A dummy is ε-happy on a column priced within ε of the lowest price. Taking the u
    cheapest columns not yet held by dummies (r_1 ≤ … ≤ r_u, the next is r_{u+1}) and
    setting every dummy-held price to B = min(max(r_u, level), r_{u+1}) + ε keeps all
    dummies ε-happy (the old level is ≤ lowest + ε ≤ r_{u+1} + ε, so B ≥ every old
    dummy price and B ≤ the new lowest + ε) and raises each taken price by ≥ ε, as a
    run of single dummy bids would, without the ε-sized price war among dummies.
    """
    p = s.prices.shape[0]
    is_dummy = s.owner == k
    u = p - k - jnp.sum(is_dummy)
    key = jnp.where(is_dummy, jnp.inf, s.prices)
    # Cheapest first; at equal price take free columns before displacing a real row.
    order = jnp.lexsort(((s.owner < k).astype(jnp.int32), key))
    ranked = key[order]
    rank = jnp.zeros((p,), jnp.int32).at[order].set(jnp.arange(p, dtype=jnp.int32))
    taken = rank < u
    r_u = ranked[jnp.clip(u - 1, 0, p - 1)]
    r_next = ranked[jnp.clip(u, 0, p - 1)]
    level = jnp.where(jnp.any(is_dummy), s.level, -jnp.inf)
    block = jnp.minimum(jnp.maximum(r_u, level), r_next) + s.eps
    outbid = jnp.where(taken & (s.owner < k), s.owner, k)
    is_dummy = is_dummy | taken
    active = u > 0
    return s._replace(
        assign=jnp.where(active, s.assign.at[outbid].set(-1, mode="drop"), s.assign),
        owner=jnp.where(taken, k, s.owner),
        prices=jnp.where(active & is_dummy, block, s.prices),
        level=jnp.where(active, block, s.level),
    )


def _greedy_fill(cost: jax.Array, assign: jax.Array) -> jax.Array:
    """Gives each unassigned row, in row order, its cheapest column not yet used."""
    k, p = cost.shape

    def fill(i, carry):
        out, used = carry
        col = jnp.argmin(jnp.where(used, jnp.inf, cost[i])).astype(jnp.int32)
        col = jnp.where(out[i] >= 0, out[i], col)
        return out.at[i].set(col), used.at[col].set(True)

    used = jnp.zeros((p,), bool).at[jnp.where(assign >= 0, assign, p)].set(True, mode="drop")
    return jax.lax.fori_loop(0, k, fill, (assign, used))[0]


def auction_solve(
    cost: jax.Array,
    eps_final: float | jax.Array | None = None,
    max_iters: int | jax.Array | None = None,
) -> AuctionResult:
    """Minimum-cost rectangular assignment by the forward auction with ε-scaling.

    Pure and jittable with fixed shapes; vmap it over a batch of problems.

    Args:
      cost: (K, P) costs, K ≤ P, float or integer (cast to float).
      eps_final: tolerance per row, in cost units; the total cost is within
        K·eps_final of the optimum. Default 1e-4 × (max − min of cost). Values below
        about 4e-6 × the range are raised to it (float32 price resolution).
      max_iters: cap on bidding rounds over all ε phases (default
        `CurriculumConfig.auction_max_iters`). When it is hit, unassigned rows take the
        cheapest unused columns in row order, so the assignment is still valid, and
        `converged` is False.

    Returns:
      AuctionResult: `assignment` (K,) int32 distinct columns, `prices` (P,) column
      prices in cost units (row i's column minimises cost[i, j] + prices[j] within
      the final ε), `converged` () bool and `iterations` () int32.
    """
    cost = jnp.asarray(cost)
    cost = cost.astype(jnp.promote_types(cost.dtype, jnp.float32))
    k, p = cost.shape
    if k > p:
        raise ValueError(f"auction needs K <= P rows <= columns, got cost of shape {cost.shape}")
    dtype = cost.dtype
    low, high = jnp.min(cost), jnp.max(cost)
    spread = high - low
    flat = spread <= 0  # every assignment is optimal
    scale = jnp.where(flat, 1.0, spread)
    # Normalised benefits in [-1, 0]: ε and prices are then O(1), well within float32.
    benefit = -(cost - low) / scale

    eps_abs = 1e-4 * scale if eps_final is None else jnp.asarray(eps_final, dtype)
    # Dummy rows add their own slack: bound min(2K, P)·ε must stay ≤ K·eps_final.
    eps_target = eps_abs / scale * (k / min(2 * k, p)) * _EPS_MARGIN
    eps_target = jnp.maximum(eps_target, _EPS_FLOOR_ULPS * jnp.finfo(dtype).eps).astype(dtype)
    cap = _DEFAULT_MAX_ITERS if max_iters is None else max_iters

    cols = jnp.arange(p, dtype=jnp.int32)
    init = _Loop(
        assign=jnp.where(flat, jnp.arange(k, dtype=jnp.int32), -1),
        owner=jnp.where(flat, jnp.where(cols < k, cols, k), k + 1),
        prices=jnp.zeros((p,), dtype),
        level=jnp.zeros((), dtype),
        eps=jnp.where(flat, eps_target, jnp.maximum(_EPS_START, eps_target)).astype(dtype),
        it=jnp.zeros((), jnp.int32),
    )

    def done(s: _Loop) -> jax.Array:
        return jnp.all(s.assign >= 0) & (s.eps <= eps_target)

    def cond(s: _Loop) -> jax.Array:
        return ~done(s) & (s.it < cap)

    def body(s: _Loop) -> _Loop:
        # A complete assignment at ε > target ends a phase (Bertsekas 1988, §4).
        s = jax.lax.cond(
            jnp.all(s.assign >= 0), lambda t: _new_phase(benefit, t, eps_target), lambda t: t, s
        )
        s = _bid_round(benefit, s)
        if p > k:
            # Only rounds that displaced a dummy (or the first) need the dummies to bid.
            needed = jnp.sum(s.owner == k) < p - k
            s = jax.lax.cond(needed, lambda t: _dummy_step(t, k), lambda t: t, s)
        return s._replace(it=s.it + 1)

    s = jax.lax.while_loop(cond, body, init)
    converged = done(s)
    assignment = jax.lax.cond(converged, lambda a: a, lambda a: _greedy_fill(cost, a), s.assign)
    return AuctionResult(assignment, s.prices * scale, converged, s.it)


def auction(
    cost: jax.Array,
    eps_final: float | jax.Array | None = None,
    max_iters: int | jax.Array | None = None,
) -> jax.Array:
    """Row → column assignment minimising the total cost; see `auction_solve`.

    Args:
      cost: (K, P) costs, K ≤ P.
      eps_final: per-row tolerance in cost units (default 1e-4 × the cost range).
      max_iters: cap on bidding rounds (default `CurriculumConfig.auction_max_iters`).

    Returns:
      (K,) int32 distinct columns; total cost within K·eps_final of the optimum.
    """
    return auction_solve(cost, eps_final, max_iters).assignment
