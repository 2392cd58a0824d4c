"""ALP-GMM's EM fit against scikit-learn's GaussianMixture from the same start."""

import jax.numpy as jnp
import numpy as np
import pytest

from d2c_jax.curricula import gmm

sklearn_mixture = pytest.importorskip("sklearn.mixture")


def _data():
    """A fixed 2-D data set: three blobs of 200, 150 and 100 points."""
    rng = np.random.default_rng(0)
    blobs = [
        rng.multivariate_normal([0.0, 0.0], [[1.0, 0.3], [0.3, 0.5]], 200),
        rng.multivariate_normal([4.0, 1.0], [[0.6, -0.2], [-0.2, 0.8]], 150),
        rng.multivariate_normal([1.0, 5.0], [[0.3, 0.0], [0.0, 1.2]], 100),
    ]
    return np.concatenate(blobs).astype(np.float64)


def _init():
    weights = np.array([0.3, 0.3, 0.4])
    means = np.array([[0.5, 0.5], [3.0, 0.0], [0.0, 4.0]])
    precisions = np.stack([np.eye(2), np.eye(2) * 2.0, np.eye(2) * 0.5])
    return weights, means, precisions


def test_em_fit_matches_scikit_learn_from_the_same_start():
    x = _data()
    weights, means, precisions = _init()
    ref = sklearn_mixture.GaussianMixture(
        3, covariance_type="full", tol=1e-3, reg_covar=1e-6, max_iter=100,
        weights_init=weights, means_init=means, precisions_init=precisions,
    ).fit(x)  # fmt: skip
    ours = gmm.fit(jnp.asarray(x, jnp.float32), gmm.from_precisions(weights, means, precisions),
                   reg_covar=1e-6, tol=1e-3, max_iter=100)  # fmt: skip
    np.testing.assert_allclose(ours.mixture.weights, ref.weights_, atol=1e-3)
    np.testing.assert_allclose(ours.mixture.means, ref.means_, atol=1e-3)
    np.testing.assert_allclose(ours.mixture.covariances, ref.covariances_, atol=1e-3)
    assert bool(ours.converged) and int(ours.n_iter) == ref.n_iter_
    np.testing.assert_allclose(ours.log_likelihood, ref.lower_bound_, atol=1e-3)


def test_zero_weight_rows_are_ignored():
    """Rows of weight 0 (an unfilled history) change nothing."""
    x = _data()
    weights, means, precisions = _init()
    init = gmm.from_precisions(weights, means, precisions)
    padded = np.concatenate([x, np.full((50, 2), 100.0)])
    row_weights = np.concatenate([np.ones(len(x)), np.zeros(50)])
    a = gmm.fit(jnp.asarray(x, jnp.float32), init)
    b = gmm.fit(jnp.asarray(padded, jnp.float32), init, row_weights=jnp.asarray(row_weights))
    np.testing.assert_allclose(a.mixture.means, b.mixture.means, atol=1e-4)
    np.testing.assert_allclose(a.mixture.covariances, b.mixture.covariances, atol=1e-4)
