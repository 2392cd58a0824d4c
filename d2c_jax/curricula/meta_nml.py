"""Meta-NML: OUTPACE's uncertainty-aware success classifier (docs/BASELINES.md, "OUTPACE").

Conditional normalised maximum likelihood (CNML) asks, for a query x: how well can the
classifier fit the data with x labelled 1, and with x labelled 0? With q_c the
probability the classifier gives label c at x after being fitted with (x, c) added,

    p_NML(1 | x) = q_1 / (q_0 + q_1),

which is near 0.5 wherever one extra point can flip the answer (unexplored space) and
near the data's label where many points agree. Refitting per query is too costly, so
meta-NML (Li et al. 2021, as OUTPACE uses it) meta-learns an initialisation from which ONE
gradient step on the query plus a few weighted context points approximates that refit
(MAML, second order). Here the per-query adaptation is `jax.vmap`ped over queries.

The classifier is unconditional: input a goal-space point, output 2 logits (success or
not). Positives are the desired examples, negatives visited achieved goals.
"""

from __future__ import annotations

from typing import NamedTuple

import flax.linen as nn
import jax
import jax.numpy as jnp
import optax

from d2c_jax.core import networks

# Distance weights exp(-DISTANCE_DECAY * ||x_q - x_j|| / threshold) of context and test
# points around a query (outpace_official meta-nml/maml/metadatasets/nml.py, the
# `dist_weight_thresh` weighting: 2.3 makes the weight 0.1 at one threshold).
DISTANCE_DECAY = 2.3


class MetaNMLSettings(NamedTuple):
    """Static settings (docs/BASELINES.md gives each one's source)."""

    inner_step: float  # SGD step of the one adaptation step (MetaNML default 0.01)
    context_points: int  # points besides the query in an adaptation batch (63)
    query_weight_inner: float  # the query's weight in the adaptation batch (1/32)
    query_weight_outer: float  # the query's weight in the meta-test loss (1/2)
    distance_scale: float  # inputs (and distances) are multiplied by this first


class Classifier(nn.Module):
    """An MLP from a goal-space point (..., d) to 2 logits (..., 2): "not desired", "desired"."""

    hidden_sizes: tuple[int, ...]
    input_scale: float = 1.0

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        return networks.MLP(self.hidden_sizes, 2)(x * self.input_scale)


def weighted_cross_entropy(net, params, x, y, w) -> jax.Array:
    """sum_j w_j CE(f(x_j), y_j) / sum_j w_j: x (n, d), y (n,) int32 labels, w (n,) -> ()."""
    logits = net.apply(params, x)
    ce = optax.softmax_cross_entropy_with_integer_labels(logits, y)
    return jnp.sum(w * ce) / jnp.maximum(jnp.sum(w), 1e-12)


def adapt(net, params, x, y, w, step: float):
    """params after one SGD step on the weighted cross-entropy of (x, y, w)."""
    grads = jax.grad(weighted_cross_entropy, argnums=1)(net, params, x, y, w)
    return jax.tree.map(lambda p, g: p - step * g, params, grads)


def distance_weights(query: jax.Array, points: jax.Array, scale: float) -> jax.Array:
    """exp(-2.3 * scale * ||query - points_j||): query (d,), points (n, d) -> (n,)."""
    return jnp.exp(-DISTANCE_DECAY * scale * jnp.linalg.norm(points - query, axis=-1))


def _with_query(query, label, weight, x, y, w):
    """The batch with the query (label, weight) first: (1 + n, d), (1 + n,), (1 + n,)."""
    return (
        jnp.concatenate([query[None], x]),
        jnp.concatenate([jnp.asarray(label, jnp.int32)[None], y]),
        jnp.concatenate([jnp.asarray(weight, jnp.float32)[None], w]),
    )


def nml_probability(net, params, query, context_x, context_y, s: MetaNMLSettings) -> jax.Array:
    """p_NML(1 | query) from the meta-learned params (module docstring).

    Args:
      query: (d,) the point.
      context_x: (2, n, d) context points, one draw for each proposed label c = 0, 1.
      context_y: (2, n) int32 their labels.
    Returns:
      () q_1 / (q_0 + q_1).
    """

    def q(label):
        x, y = context_x[label], context_y[label]
        w = distance_weights(query, x, s.distance_scale)
        batch = _with_query(query, label, s.query_weight_inner, x, y, w)
        adapted = adapt(net, params, *batch, s.inner_step)
        return jax.nn.softmax(net.apply(adapted, query))[label]

    q0, q1 = q(0), q(1)
    return q1 / (q0 + q1)


def nml_probabilities(
    net, params, queries, pool_x, pool_y, key, s: MetaNMLSettings, chunk: int = 256
) -> jax.Array:
    """p_NML(1 | x) for every query (Q, d) -> (Q,).

    Each query adapts on its own random `s.context_points` points of the labelled pool
    (pool_x (M, d), pool_y (M,) int32), drawn independently for the two labels as
    OUTPACE does; queries are vmapped in chunks of `chunk` (memory: a chunk holds one
    adapted parameter set per query).
    """
    n_q = queries.shape[0]
    idx = jax.random.randint(key, (n_q, 2, s.context_points), 0, pool_x.shape[0])

    def one(args):
        query, ids = args
        return nml_probability(net, params, query, pool_x[ids], pool_y[ids], s)

    return jax.lax.map(one, (queries, idx), batch_size=min(chunk, n_q))


def meta_task_loss(net, params, query, label, context, test, s: MetaNMLSettings) -> jax.Array:
    """One MAML task's meta-test loss (second order: differentiate it w.r.t. params).

    Adapt on the query with its proposed label (weight `query_weight_inner`) plus the
    distance-weighted context; then the weighted cross-entropy on the distance-weighted
    test points plus the query (weight `query_weight_outer`).

    Args:
      query: (d,); label: () int32 proposed label.
      context: (x (n, d), y (n,)) context points; test: (x (m, d), y (m,)) test points.
    """
    cx, cy = context
    inner = _with_query(query, label, s.query_weight_inner, cx, cy,
                        distance_weights(query, cx, s.distance_scale))  # fmt: skip
    adapted = adapt(net, params, *inner, s.inner_step)
    tx, ty = test
    outer = _with_query(query, label, s.query_weight_outer, tx, ty,
                        distance_weights(query, tx, s.distance_scale))  # fmt: skip
    return weighted_cross_entropy(net, adapted, *outer)


def meta_train_step(net, optimizer, params, opt_state, train, test, key, s, tasks: int):
    """One outer Adam step on the mean loss of `tasks` tasks (OUTPACE accumulates 16).

    Each task: a query drawn from `train` (x (n, d), y (n,)) with a random proposed label
    (OUTPACE's task list gives each query one proposed label), its context drawn from
    `test` (x (m, d), y (m,)), and `test` itself as the meta-test set.

    Returns:
      (params, opt_state, () mean meta-test loss).
    """
    k_q, k_label, k_ctx = jax.random.split(key, 3)
    train_x, _ = train
    test_x, test_y = test
    q_idx = jax.random.randint(k_q, (tasks,), 0, train_x.shape[0])
    labels = jax.random.bernoulli(k_label, 0.5, (tasks,)).astype(jnp.int32)
    ctx_idx = jax.random.randint(k_ctx, (tasks, s.context_points), 0, test_x.shape[0])

    def mean_loss(p):
        per_task = jax.vmap(
            lambda q, c, ids: meta_task_loss(net, p, q, c, (test_x[ids], test_y[ids]), test, s)
        )(train_x[q_idx], labels, ctx_idx)
        return per_task.mean()

    loss, grads = jax.value_and_grad(mean_loss)(params)
    updates, opt_state = optimizer.update(grads, opt_state, params)
    return optax.apply_updates(params, updates), opt_state, loss
