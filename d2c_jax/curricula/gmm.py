"""A Gaussian mixture fitted by EM in JAX (full covariances), for ALP-GMM's teacher.

The same algorithm as scikit-learn's `GaussianMixture(covariance_type="full")` started
from given weights, means and precisions: alternate an E-step (responsibilities, the mean
log-likelihood) and an M-step (weights, means, covariances + reg_covar * I) until the mean
log-likelihood changes by less than `tol`, at most `max_iter` times. Fixed shapes: rows
carry a weight (0 for rows of a history that is not yet full), so the fit stays inside
the jitted iteration.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

# scikit-learn adds 10 * float eps to each component's responsibility mass, so that an
# empty component does not divide by zero; the same here, at float32.
_MASS_EPS = 10 * float(jnp.finfo(jnp.float32).eps)


class Mixture(NamedTuple):
    """A k-component mixture in d dimensions."""

    weights: jax.Array  # (k,) mixing weights, summing to 1
    means: jax.Array  # (k, d)
    covariances: jax.Array  # (k, d, d)


class Fit(NamedTuple):
    """The result of `fit`."""

    mixture: Mixture
    log_likelihood: jax.Array  # () mean log-likelihood per (weighted) row at the last E-step
    n_iter: jax.Array  # () int32 EM iterations run
    converged: jax.Array  # () bool the change fell below tol


def log_densities(x: jax.Array, mixture: Mixture) -> jax.Array:
    """log(w_k N(x_i; mu_k, Sigma_k)): x (n, d) -> (n, k), by Cholesky factors."""
    chol = jnp.linalg.cholesky(mixture.covariances)  # (k, d, d)
    diff = x[None, :, :] - mixture.means[:, None, :]  # (k, n, d)
    solved = jax.scipy.linalg.solve_triangular(chol, jnp.swapaxes(diff, 1, 2), lower=True)
    mahalanobis = jnp.sum(solved**2, axis=1)  # (k, n)
    log_det = 2.0 * jnp.sum(jnp.log(jnp.diagonal(chol, axis1=1, axis2=2)), axis=-1)  # (k,)
    d = x.shape[-1]
    log_gauss = -0.5 * (d * jnp.log(2.0 * jnp.pi) + log_det[:, None] + mahalanobis)
    return (log_gauss + jnp.log(mixture.weights)[:, None]).T


def e_step(x: jax.Array, mixture: Mixture, row_weights: jax.Array) -> tuple[jax.Array, jax.Array]:
    """(weighted mean log-likelihood (), log responsibilities (n, k))."""
    joint = log_densities(x, mixture)
    norm = jax.scipy.special.logsumexp(joint, axis=1)  # (n,)
    mean_ll = jnp.sum(row_weights * norm) / jnp.maximum(row_weights.sum(), 1e-12)
    return mean_ll, joint - norm[:, None]


def m_step(x: jax.Array, log_resp: jax.Array, row_weights: jax.Array, reg_covar: float) -> Mixture:
    """Weights, means and covariances (+ reg_covar I) from responsibilities (n, k)."""
    resp = jnp.exp(log_resp) * row_weights[:, None]
    mass = resp.sum(axis=0) + _MASS_EPS  # (k,)
    means = resp.T @ x / mass[:, None]
    diff = x[None, :, :] - means[:, None, :]  # (k, n, d)
    cov = jnp.einsum("kn,kni,knj->kij", resp.T, diff, diff) / mass[:, None, None]
    cov = cov + reg_covar * jnp.eye(x.shape[-1])
    return Mixture(weights=mass / mass.sum(), means=means, covariances=cov)


def fit(
    x: jax.Array,
    init: Mixture,
    *,
    row_weights: jax.Array | None = None,
    reg_covar: float = 1e-6,
    tol: float = 1e-3,
    max_iter: int = 100,
) -> Fit:
    """EM from `init` on rows x (n, d) (row_weights (n,), default all 1)."""
    row_weights = jnp.ones(x.shape[0]) if row_weights is None else row_weights

    def keep_going(carry):
        _, ll, prev, n_iter = carry
        return (n_iter < max_iter) & ~(jnp.abs(ll - prev) < tol)

    def one(carry):
        mixture, ll, _, n_iter = carry
        new_ll, log_resp = e_step(x, mixture, row_weights)
        return m_step(x, log_resp, row_weights, reg_covar), new_ll, ll, n_iter + 1

    start = (init, jnp.asarray(-jnp.inf), jnp.asarray(jnp.nan), jnp.zeros((), jnp.int32))
    mixture, ll, prev, n_iter = jax.lax.while_loop(keep_going, one, start)
    return Fit(mixture, ll, n_iter, jnp.abs(ll - prev) < tol)


def from_precisions(weights, means, precisions) -> Mixture:
    """A `Mixture` from precision matrices (scikit-learn's `precisions_init`)."""
    return Mixture(
        jnp.asarray(weights), jnp.asarray(means), jnp.linalg.inv(jnp.asarray(precisions))
    )
