"""The jitted auction against scipy's exact assignment (SPEC §5a)."""

import inspect

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.optimize import linear_sum_assignment

from d2c_jax.config import CurriculumConfig
from d2c_jax.curricula import matching

# (K, P) shapes from 1x1 to 64x256; 25 problems each, solved as one vmapped batch.
SHAPES = [(1, 1), (1, 9), (3, 7), (8, 8), (20, 100), (17, 33), (64, 64), (64, 256)]
PER_SHAPE = 25
SOLVE = jax.jit(jax.vmap(matching.auction_solve))


def make_problem(rng, k, p, kind):
    """A (K, P) cost matrix of one of five kinds, at a random scale in [1e-3, 1e3]."""
    scale = 10 ** rng.uniform(-3, 3)
    offset = rng.uniform(-1, 1) * scale  # negative costs too
    if kind == 0:  # continuous
        return rng.uniform(0, 1, (k, p)) * scale + offset
    if kind == 1:  # many ties
        return np.round(rng.uniform(0, 3, (k, p))) * scale + offset
    if kind == 2:  # duplicate rows
        c = rng.uniform(0, 1, (k, p)) * scale + offset
        c[k // 2 :] = c[: k - k // 2]
        return c
    if kind == 3:  # small integers: the auction must be exactly optimal
        return rng.integers(-3, 4, (k, p)).astype(np.float64)
    return rng.normal(size=(k, p)) * scale  # signed, heavy mass near 0


def assert_valid(assignment, k, p):
    a = np.asarray(assignment)
    assert a.shape == (k,) and a.dtype == np.int32
    assert a.min() >= 0 and a.max() < p
    assert len(set(a.tolist())) == k  # distinct columns


@pytest.mark.parametrize("shape", SHAPES)
def test_auction_within_k_eps_of_scipy_optimum(shape):
    k, p = shape
    rng = np.random.default_rng(k * 1000 + p)
    kinds = [i % 5 for i in range(PER_SHAPE)]
    costs = np.stack([make_problem(rng, k, p, kind) for kind in kinds]).astype(np.float32)
    result = SOLVE(jnp.asarray(costs))
    assert np.asarray(result.converged).all()
    for cost, assignment, kind in zip(
        costs.astype(np.float64), result.assignment, kinds, strict=True
    ):
        assert_valid(assignment, k, p)
        rows, cols = linear_sum_assignment(cost)
        optimum = cost[rows, cols].sum()
        got = cost[np.arange(k), np.asarray(assignment)].sum()
        eps_final = 1e-4 * (cost.max() - cost.min())
        float32_slack = 1e-5 * np.abs(cost).sum() / p  # the costs themselves are float32
        assert got <= optimum + k * eps_final + float32_slack
        if kind == 3:
            assert got == optimum  # integer costs, eps < 1/K: exact


def test_degenerate_matrices_are_valid_assignments():
    for cost in (np.zeros((5, 9)), np.full((4, 4), 3.5), np.full((1, 1), -2.0)):
        result = matching.auction_solve(jnp.asarray(cost, jnp.float32))
        assert_valid(result.assignment, *cost.shape)
        assert bool(result.converged)


def test_jit_vmap_and_plain_call_agree():
    rng = np.random.default_rng(0)
    costs = rng.uniform(-5, 5, (6, 20, 100)).astype(np.float32)
    batched = np.asarray(SOLVE(jnp.asarray(costs)).assignment)
    for cost, a in zip(costs, batched, strict=True):
        np.testing.assert_array_equal(jax.jit(matching.auction)(jnp.asarray(cost)), a)
    np.testing.assert_array_equal(matching.auction(jnp.asarray(costs[0])), batched[0])


def test_iteration_cap_still_gives_a_valid_assignment():
    rng = np.random.default_rng(1)
    cost = jnp.asarray(rng.uniform(0, 1, (64, 256)), jnp.float32)
    result = matching.auction_solve(cost, max_iters=2)
    assert not bool(result.converged)
    assert int(result.iterations) <= 2
    assert_valid(result.assignment, 64, 256)


def test_custom_eps_final_bounds_the_gap():
    rng = np.random.default_rng(2)
    cost = rng.uniform(0, 10, (20, 100))
    a = np.asarray(matching.auction(jnp.asarray(cost, jnp.float32), eps_final=0.5))
    rows, cols = linear_sum_assignment(cost)
    assert cost[np.arange(20), a].sum() <= cost[rows, cols].sum() + 20 * 0.5 + 1e-3


def test_default_iteration_cap_is_the_curriculum_config_s():
    """The contract's signature, and one default cap: `max_iters=None` is the config's."""
    params = inspect.signature(matching.auction).parameters
    assert list(params) == ["cost", "eps_final", "max_iters"]
    assert params["eps_final"].default is None and params["max_iters"].default is None
    assert matching._DEFAULT_MAX_ITERS == CurriculumConfig().auction_max_iters == 100_000
