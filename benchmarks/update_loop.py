"""Updates per compiled loop iteration: our SAC+HER against brax SAC (issue 21 §2).

    python -m benchmarks.update_loop [--size small] [--variants 1 2] [--epochs 7]

For each value v of `--variants`, our SAC+HER row of the throughput table (settings of
`benchmarks.trainer.throughput_configs`: one update per env step, actor and target at
every update) is compiled with `sac_loop.MIN_UPDATES_PER_LOOP_ITERATION = v`; then brax SAC
trains `--epochs` timed epochs, and before each one a timed round of every variant runs
(`benchmarks.trainer.alternate_rounds`), so all of them see the same machine. Prints each
variant's env steps/s and its ratio to brax SAC (best / best and the paired median).
"""

from __future__ import annotations

import argparse
import sys

from benchmarks import brax_sac, results, trainer
from benchmarks.sac_update import SIZES
from d2c_jax.training import sac_loop


def variant_rates(size: str, variants: list[int], epochs: int) -> tuple[list, dict]:
    """brax SAC's env steps/s per timed epoch, and ours per variant: name -> list."""
    default = sac_loop.MIN_UPDATES_PER_LOOP_ITERATION
    ours = {}
    try:
        for v in variants:  # read when the step is traced, so set it before each compile
            sac_loop.MIN_UPDATES_PER_LOOP_ITERATION = v
            config = trainer.throughput_configs(size)["SAC+HER"]
            ours[f"{v} per iteration"] = trainer.TimedRun(config)
    finally:
        sac_loop.MIN_UPDATES_PER_LOOP_ITERATION = default
    return rates_beside_brax(size, ours, epochs)


def rates_beside_brax(
    size: str, ours: dict[str, trainer.TimedRun], epochs: int
) -> tuple[list[float], dict[str, list[float]]]:
    """brax SAC's env steps/s over `epochs` timed epochs at SIZES[size], with one timed
    round of each of `ours` before every one of them: (brax's rates, name -> our rates)."""
    rounds: list[dict[str, float]] = []
    brax = brax_sac.epoch_rates(
        size, timed_epochs=epochs, after_epoch=lambda: rounds.append(trainer.alternate_rounds(ours))
    )
    return brax, {name: [r[name] for r in rounds] for name in ours}


def print_ratios(brax: list[float], ours: dict[str, list[float]]) -> None:
    """Each variant's env steps/s and its ratio to brax SAC (best / best, paired median)."""
    print("brax SAC env steps/s:", [round(x, 1) for x in brax])
    for name, rates in ours.items():
        print(
            f"{name}: {[round(x, 1) for x in rates]}, best/best {max(rates) / max(brax):.3f}x, "
            f"paired median {results.paired_ratio(rates, brax):.3f}x",
            flush=True,
        )


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", default="small", choices=list(SIZES))
    parser.add_argument("--variants", nargs="+", type=int, default=[1, 2])
    parser.add_argument("--epochs", type=int, default=7)
    args = parser.parse_args(argv)
    if args.epochs < 1 or min(args.variants) < 1:
        print("error: --epochs and every --variants value must be >= 1", file=sys.stderr)
        return 2
    print_ratios(*variant_rates(args.size, args.variants, args.epochs))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
