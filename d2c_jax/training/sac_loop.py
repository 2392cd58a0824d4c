"""The SAC part of an iteration's updates (SPEC §2 step 4, §4): blocks of SAC updates, each
update on its own HER batch, with the transitions drawn ahead a chunk at a time.

`sac_blocks` is a pure function of the SAC state, the buffer and the reward; the agent
(`d2c_jax.training.agent.Agent.sac_blocks`) supplies the current classifier's reward and
interleaves these blocks with the classifier's updates.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from d2c_jax import config as config_lib
from d2c_jax.core import her, networks, replay, sac
from d2c_jax.core.types import RewardFn
from d2c_jax.training.state import Hyperparams

# SAC blocks whose HER transitions `sac_blocks` draws at once: 64 x 2 x 256 rows at the
# quick preset; on Ant at the paper's batch, 64 x 512 rows of 70 floats (9 MB). Read when
# the step is traced.
SAMPLE_CHUNK = 64

# SAC updates in one iteration of the update loop's compiled body, at least: blocks of
# fewer updates are unrolled (`lax.scan`'s unroll) up to it. XLA:CPU copies the SAC
# parameters that its YNNPACK matmuls read at the top of every loop iteration (so that Adam
# can then overwrite them in place), so two updates per iteration halve those copies for
# one-update blocks (actor and target every update: the throughput benchmark's settings).
# Measured on 2 Intel Xeon cores, SAC+HER at 2x256: 0.90x brax SAC's env steps/s with one
# update per iteration, 1.00x with 2 and 4, 0.97x with 8 (paired medians of 6 rounds).
# The presets' two-update blocks are unchanged: unrolling them too gained nothing
# (medium_maze quick: 1.01x with 2 blocks per iteration, 0.94x with 4). benchmarks/RESULTS.md.
# Read when the step is traced.
MIN_UPDATES_PER_LOOP_ITERATION = 2


def sac_blocks(
    cfg: config_lib.TrainConfig,
    env,
    nets: networks.SACNetworks,
    optimizers: sac.Optimizers,
    hp: Hyperparams,
    sac_state: sac.SACState,
    buffer: replay.ReplayState,
    reward_fn: RewardFn,
    terminal_fn: RewardFn | None,
    n: int,
    key: jax.Array,
) -> tuple[sac.SACState, dict]:
    """`n` blocks of `sac.block_size` SAC updates (critic each, actor and target on their
    cadences); the new SAC state and the mean "sac/*" metrics.

    Each update gets its own HER batch of `cfg.sac.batch_size` transitions. The
    transitions and their relabelled goals are drawn ahead, `SAMPLE_CHUNK` blocks at a
    time (one set of gathers instead of one per update: SAC+HER's updates 6-9% faster at
    2x256); each block's rewards come from `reward_fn` inside the loop, one call on
    block_size x B rows (a classifier forward runs fastest on ~1k rows on a CPU: 50-58
    GMAC/s, 32-35 at 16k-100k rows). Each compiled loop iteration runs at least
    `MIN_UPDATES_PER_LOOP_ITERATION` updates. Block i draws from the i-th of `n` keys of
    `key`, as a block-by-block loop would. A statically unrolled block needs no `lax.cond`
    on the update counter, which under vmap (seeds) would compute the actor update at
    every step.

    Args:
      cfg: the run's config (its `sac`, `her` and `replay` sections are read).
      env: the goal env (success radius, input maps).
      nets, optimizers: the SAC networks and optimisers (`Agent.sac_nets`, ...).
      hp: the run's traced hyperparameters (`hp.sac`, `hp.relabel_prob`).
      sac_state, buffer: the SAC state to update and the replay buffer to draw from.
      reward_fn: (ag_next, goal) -> reward of a relabelled transition (SPEC §4).
      terminal_fn: where the critic stops bootstrapping, or None (SPEC §4: no terminal).
      n: number of blocks (static).
      key: PRNG key.
    """
    if n == 0:
        return sac_state, {}
    block = sac.block_size(cfg.sac)
    min_future = cfg.her.min_future_radii * env.success_radius
    keys = jax.random.split(key, n)
    size = min(n, SAMPLE_CHUNK)
    unroll = -(-MIN_UPDATES_PER_LOOP_ITERATION // block)
    full = n - n % size

    def draw_block(key):  # -> leaves (block_size, B, ...)
        draw = lambda k: her.sample_relabelled(  # noqa: E731
            hp.relabel_prob,
            buffer,
            cfg.sac.batch_size,
            k,
            cfg.replay.walk_fraction,
            min_future,
            cfg.her.random_prob,
            cfg.her.n_step,
        )
        return jax.vmap(draw)(jax.random.split(key, block))

    def update_block(sac_state, drawn_and_key):
        drawn, key = drawn_and_key
        batches = jax.vmap(lambda tr: her.with_reward(tr, reward_fn, terminal_fn, cfg.sac.gamma))(
            drawn
        )
        return sac.update_sac_block(cfg.sac, nets, optimizers, hp.sac, sac_state, batches, env, key)

    def chunk(sac_state, chunk_keys):  # (m,) keys -> m blocks
        draw_keys, update_keys = jax.vmap(jax.random.split, out_axes=1)(chunk_keys)
        drawn = jax.vmap(draw_block)(draw_keys)
        return jax.lax.scan(update_block, sac_state, (drawn, update_keys), unroll=unroll)

    sac_state, metrics = jax.lax.scan(chunk, sac_state, keys[:full].reshape(-1, size))
    metrics = jax.tree.map(lambda x: x.reshape(-1), metrics)  # (full,) per block
    if full < n:
        sac_state, rest = chunk(sac_state, keys[full:])
        metrics = jax.tree.map(lambda a, b: jnp.concatenate([a, b]), metrics, rest)
    return sac_state, jax.tree.map(jnp.mean, metrics)
