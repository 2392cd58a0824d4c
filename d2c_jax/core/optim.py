"""Adam with a traced step size: the optimiser is static, its learning rate a value of
the hyperparameter pytree (`TrainState.hparams`), so a sweep can vmap over it."""

from __future__ import annotations

import jax
import optax


def adam() -> optax.GradientTransformation:
    """Adam (optax defaults) without its learning rate: `optax.adam(lr)` is this followed
    by a scaling by -lr, which `adam_step` applies with a traced lr (bitwise the same)."""
    return optax.scale_by_adam()


def adam_step(opt: optax.GradientTransformation, lr: jax.Array, grads, opt_state, params):
    """One Adam step of size lr: (params - lr * adam_direction(grads), new opt_state)."""
    direction, opt_state = opt.update(grads, opt_state, params)
    updates = jax.tree.map(lambda d: -lr * d, direction)
    return optax.apply_updates(params, updates), opt_state
