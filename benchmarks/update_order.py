"""The order of SAC's steps within an update, in the whole loop, against brax SAC (issue 21 §2).

    python -m benchmarks.update_order [--size paper] [--epochs 3]

Ours steps the critic and then the actor against the just-updated critic (the order of
D2C's and OUTPACE's code, and SB3's). brax computes its alpha, critic and actor steps
from the same pre-update parameters, so the three are independent and XLA may run them
side by side; on 2026-12-04 that was the suspected cause of the gap at 3x512
(benchmarks/RESULTS.md). This benchmark tests the suspicion: our SAC+HER row of the
throughput table compiled twice, as it is ("critic first") and with brax's order
("simultaneous", built here from `d2c_jax.core.sac`'s own steps, for the throughput
settings' one-update blocks only), each timed for one round before every timed brax epoch
(`benchmarks.trainer.alternate_rounds`). Prints env steps/s and the ratios to brax SAC.
The package keeps its order: this is a measurement, not an option.
"""

from __future__ import annotations

import argparse
import sys

import jax

from benchmarks import results, trainer, update_loop
from benchmarks.sac_update import SIZES
from d2c_jax.core import sac


def simultaneous_block(cfg, nets, opt, hp, state, batches, env, key):
    """`sac.update_sac_block` for a one-update block (actor, alpha and target at every
    update), with the critic and the actor-and-alpha steps both taken from `state`."""
    assert sac.block_size(cfg) == 1, "brax's order is built for one-update blocks only"
    batch = jax.tree.map(lambda x: x[0], batches)
    key_critic, key_actor = jax.random.split(jax.random.split(key, 1)[0])
    feats, next_feats = sac._features(nets, env, batch)
    stepped, metrics = sac._critic_step(
        cfg, nets, opt, hp, state, feats, next_feats, batch, key_critic
    )
    acted = sac._actor_step(cfg, nets, opt, hp, state, feats, env.action_dim, key_actor)
    stepped = stepped.replace(
        actor_params=acted.actor_params,
        actor_opt=acted.actor_opt,
        actor_loss=acted.actor_loss,
        log_alpha=acted.log_alpha,
        alpha_opt=acted.alpha_opt,
    )
    return sac._finish(sac._polyak(stepped, hp.tau), metrics)


def order_rates(size: str, epochs: int) -> tuple[list[float], dict[str, list[float]]]:
    """brax SAC's env steps/s per timed epoch, and ours per order: name -> list."""
    config = trainer.throughput_configs(size)["SAC+HER"]
    default = sac.update_sac_block
    ours = {"critic first": trainer.TimedRun(config)}
    try:  # read when the step is traced, so swapped around one compile only
        sac.update_sac_block = simultaneous_block
        ours["simultaneous"] = trainer.TimedRun(config)
    finally:
        sac.update_sac_block = default
    return update_loop.rates_beside_brax(size, ours, epochs)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", default="paper", choices=list(SIZES))
    parser.add_argument("--epochs", type=int, default=3)
    args = parser.parse_args(argv)
    if args.epochs < 1:
        print("error: --epochs must be >= 1", file=sys.stderr)
        return 2
    print(results.hardware(), flush=True)
    update_loop.print_ratios(*order_rates(args.size, args.epochs))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
