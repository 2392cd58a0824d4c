"""Matching benchmark: the jitted auction vs scipy vs optax's jitted Hungarian algorithm.

    python -m benchmarks.matching [--write]

Sizes (20, 100) (the curriculum's K x P), (256, 512) and (1024, 2048); each single and
vmapped over 16 problems; uniform random costs. Times are medians after compilation;
the gap is the total cost above scipy's optimum, relative to the optimum's magnitude.
`--write` replaces the "Matching" section of benchmarks/RESULTS.md.
"""

from __future__ import annotations

import argparse
import statistics
import time

import jax
import jax.numpy as jnp
import numpy as np
import optax
from scipy.optimize import linear_sum_assignment

from benchmarks import results
from d2c_jax.curricula import matching

SIZES = ((20, 100), (256, 512), (1024, 2048))
BATCH = 16


def median_seconds(fn, repeats: int) -> float:
    """Median wall-clock of fn() (which must block until done)."""
    fn()  # compile / warm up
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def total_cost(cost: np.ndarray, cols: np.ndarray) -> float:
    return float(cost[np.arange(cost.shape[0]), cols].sum())


def _worst_gap(costs: np.ndarray, optimum: list[float], assignments) -> float:
    """Worst relative gap over the problems given (zip stops at the shorter)."""
    return max(
        (total_cost(c.astype(np.float64), np.asarray(a)) - o) / abs(o)
        for c, a, o in zip(costs, assignments, optimum, strict=False)
    )


def _hungarian_cols(cost: jax.Array) -> jax.Array:
    """optax's Hungarian assignment as one column per row, in row order."""
    rows, cols = optax.assignment.hungarian_algorithm(cost)
    return cols[jnp.argsort(rows)]


def bench_size(k: int, p: int, repeats: int) -> list[tuple]:
    """Rows (solver, batch, seconds per call, max relative gap) for one size."""
    rng = np.random.default_rng(k)
    costs = rng.uniform(0, 1, (BATCH, k, p)).astype(np.float32)
    optimum = [total_cost(c, linear_sum_assignment(c)[1]) for c in costs.astype(np.float64)]
    auction, auction_batch = jax.jit(matching.auction), jax.jit(jax.vmap(matching.auction))
    hungarian, hungarian_batch = jax.jit(_hungarian_cols), jax.jit(jax.vmap(_hungarian_cols))
    one, batch = jnp.asarray(costs[0]), jnp.asarray(costs)
    n_gap = BATCH if k < 1024 else 2  # problems checked against scipy
    # (solver, problems per call, the timed call, its gap, whether this size runs it)
    solvers = [
        ("auction (jit)", 1, lambda: auction(one).block_until_ready(),
         lambda: [auction(c) for c in batch[:n_gap]], True),
        # 16 padded 2048 x 2048 problems at once: minutes per call on a 2-core CPU
        ("auction (jit, vmap)", BATCH, lambda: auction_batch(batch).block_until_ready(),
         lambda: auction_batch(batch), k < 1024),
        ("scipy linear_sum_assignment", 1, lambda: linear_sum_assignment(costs[0]), None, True),
        ("scipy, loop over batch", BATCH, lambda: [linear_sum_assignment(c) for c in costs],
         None, True),
        # optax's Hungarian is O(n^3) sequential steps: minutes at 1024 x 2048
        ("optax hungarian (jit)", 1, lambda: hungarian(one).block_until_ready(),
         lambda: [hungarian(c) for c in batch], k <= 256),
        ("optax hungarian (jit, vmap)", BATCH, lambda: hungarian_batch(batch).block_until_ready(),
         lambda: hungarian_batch(batch), k <= 256),
    ]  # fmt: skip
    return [
        (name, n, median_seconds(call, repeats),
         0.0 if assign is None else _worst_gap(costs, optimum, assign()))
        for name, n, call, assign, wanted in solvers
        if wanted
    ]  # fmt: skip


def run(repeats: int) -> str:
    """The markdown section."""
    lines = [
        f"Hardware: {results.hardware()}; "
        "command `python -m benchmarks.matching --write`; uniform costs in [0, 1]; median "
        "of repeated calls after compilation; gap = (cost − scipy optimum) / optimum, worst "
        f"of {BATCH} problems.",
        "",
        "| K × P | solver | problems per call | ms per call | worst gap |",
        "|---|---|---|---|---|",
    ]
    for k, p in SIZES:
        for name, n, seconds, g in bench_size(k, p, repeats if k < 1024 else 2):
            lines.append(f"| {k} × {p} | {name} | {n} | {seconds * 1e3:.2f} | {g:.1e} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--write", action="store_true", help="update benchmarks/RESULTS.md")
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args(argv)
    results.report("Matching", run(args.repeats), args.write)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
