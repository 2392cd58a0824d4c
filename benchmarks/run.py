"""Regenerates benchmarks/RESULTS.md: every comparison, each measured in this one run.

    pip install -e '.[bench]'      # SB3, gymnasium-robotics, PyTorch (brax is a core dependency)
    python -m benchmarks.run [--only throughput sac_update envs matching seeds sweep memory]
    python -m benchmarks.run --only throughput --no-sb3   # ours against brax SAC only

Sections written (each names its command and the hardware):
  "Training throughput vs SB3 and brax SAC"
                                d2c_jax SAC+HER and D2C against SB3 SAC+HER (benchmarks.sb3)
                                and brax SAC on the same MJX env (benchmarks.brax_sac)
  "SAC update"                  d2c_jax against PyTorch, against the CPU roofline
  "Environments"                MJX at batch 1/64/1024 against C MuJoCo (benchmarks.envs)
  "Matching"                    the auction against scipy and optax (benchmarks.matching)
  "Seed scaling", "Memory"      benchmarks.trainer
The "Learning" section comes from training runs (benchmarks.learning_curve), not from here.
"""

from __future__ import annotations

import argparse
import time
from typing import NamedTuple

import jax

from benchmarks import brax_sac, matching, results, sac_update, sb3, trainer
from benchmarks import envs as envs_bench
from envs import ENV_NAMES

PARTS = ("throughput", "sac_update", "envs", "matching", "seeds", "sweep", "memory")
TARGET_VS_SB3 = {"paper": 1.4, "small": 2.5}
"""Issue targets: d2c_jax SAC+HER env steps/s over SB3's at identical settings."""
TARGET_VS_BRAX = 1.0
"""Issue 21's target: d2c_jax SAC+HER env steps/s over brax SAC's at identical sizes."""
TIMED_ROUNDS = 5
"""Timed brax epochs per size, each preceded by one timed round of each of our rows."""
BRAX = "brax SAC (JAX)"
SB3 = "SB3 SAC+HER (PyTorch)"


class Throughput(NamedTuple):
    """One size's rates: tool -> (env steps/s, SAC updates/s), the best round of each;
    and, for each of our rows, the median over rounds of (our round / the brax epoch
    right after it), the ratio a load drift between rounds cannot tilt."""

    rates: dict[str, tuple[float, float]]
    paired_vs_brax: dict[str, float]


def throughput_rates(size: str, with_sb3: bool = True) -> Throughput:
    """SB3 SAC+HER (unless not `with_sb3`), brax SAC, and our SAC+HER and D2C at
    SIZES[size].

    Ours and brax alternate on the machine: before each of TIMED_ROUNDS timed brax epochs
    (2,000 env steps), one timed round (2,000 env steps) of each of our rows runs.
    """
    reference = sb3.sb3_env_steps_per_s(size) if with_sb3 else None
    ours = {
        variant: trainer.TimedRun(cfg) for variant, cfg in trainer.throughput_configs(size).items()
    }
    rounds: list[dict[str, float]] = []
    brax = brax_sac.epoch_rates(
        size,
        timed_epochs=TIMED_ROUNDS,
        after_epoch=lambda: rounds.append(trainer.alternate_rounds(ours)),
    )
    rates = {BRAX: (max(brax),) * 2}
    if reference is not None:
        rates = {SB3: (reference, reference), **rates}
    paired = {}
    for variant, run in ours.items():
        best = max(r[variant] for r in rounds)
        rates[f"d2c_jax {variant}"] = (best, best * run.updates_per_env_step)
        paired[f"d2c_jax {variant}"] = results.paired_ratio([r[variant] for r in rounds], brax)
    return Throughput(rates, paired)


def throughput_section(with_sb3: bool = True) -> str:
    """The throughput table; without SB3 (`--no-sb3`: a machine without the bench extra,
    such as a GPU image with no PyTorch RL stack) its row and the "vs SB3" column read
    n/a."""
    rows = [
        "| size (hidden, batch) | tool | env steps/s | SAC updates/s | vs SB3 | vs brax SAC "
        "(best / best) | vs brax SAC (paired median) | target |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for size in TARGET_VS_SB3:
        label = sac_update.size_label(size)
        measured = throughput_rates(size, with_sb3)
        sb3_rate = measured.rates[SB3][0] if with_sb3 else None
        brax_rate = measured.rates[BRAX][0]
        for tool, (rate, updates) in measured.rates.items():
            target = ""
            if tool == "d2c_jax SAC+HER":
                target = f">= {TARGET_VS_SB3[size]}x SB3, >= {TARGET_VS_BRAX}x brax"
            paired = measured.paired_vs_brax.get(tool)
            paired_cell = "" if paired is None else f"{paired:.2f}x"
            vs_sb3 = "n/a" if sb3_rate is None else f"{rate / sb3_rate:.2f}x"
            rows.append(
                f"| {label} | {tool} | {rate:,.1f} | {updates:,.1f} | {vs_sb3} "
                f"| {rate / brax_rate:.2f}x | {paired_cell} | {target} |"
            )
        print("\n".join(rows[-len(measured.rates) :]), flush=True)
    return "\n".join(
        [
            f"Command: `python -m benchmarks.run --only throughput"
            f"{'' if with_sb3 else ' --no-sb3'}` ({time.strftime('%Y-%m-%d')}).",
            f"Hardware: {results.hardware()}; jax {jax.__version__}.",
            (
                "SB3 on gymnasium-robotics `PointMaze_Medium-v3` (C MuJoCo, 1 env); "
                if with_sb3
                else ""
            )
            + "brax SAC and "
            "d2c_jax on our MJX `medium_maze` (brax through `envs.to_brax`), 4 envs. Identical "
            "settings: the same network sizes, batch, one gradient step per env step, actor, "
            "alpha and target every step. d2c_jax SAC+HER = D2C with sparse reward, goals from "
            "the desired set and no classifier updates; D2C adds the classifier (16 updates "
            "per 2,000 env steps), the matching curriculum and the intrinsic reward. brax SAC "
            "samples stored transitions (no HER). Rates: brax's `training/sps` of an epoch "
            "of 2,000 env steps, and our rounds of 2,000 env steps (one matching cycle); "
            f"before each of {TIMED_ROUNDS} timed brax epochs, one round of each of our rows "
            "runs (`benchmarks.brax_sac`). env steps/s: the best round. Paired median: the "
            "median over rounds of our round / the brax epoch right after it.",
            "",
            *rows,
        ]
    )


def matching_section() -> str:
    """The auction against the references, and the curriculum step's share of an iteration."""
    return f"{matching.run(repeats=5)}\n\n{trainer.curriculum_share()}"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", nargs="+", default=list(PARTS), choices=PARTS)
    parser.add_argument(
        "--no-sb3", action="store_true",
        help="throughput: leave SB3 out (no bench extra, e.g. on a GPU image)",
    )  # fmt: skip
    args = parser.parse_args(argv)
    jobs = {
        # Without SB3, a section of its own (per backend), so that a GPU run does not
        # replace the CPU table that SB3 is in.
        "throughput": (
            f"Training throughput vs brax SAC ({jax.default_backend()}, no SB3)"
            if args.no_sb3
            else "Training throughput vs SB3 and brax SAC",
            lambda: throughput_section(with_sb3=not args.no_sb3),
        ),
        "sac_update": ("SAC update", lambda: sac_update.run(list(sac_update.SIZES))),
        "envs": ("Environments", lambda: envs_bench.run(ENV_NAMES, (1, 64, 1024), 3)),
        "matching": ("Matching", matching_section),
        "seeds": ("Seed scaling", trainer.seed_scaling),
        "sweep": ("Sweeps: one program against runs one after another", trainer.sweep_scaling),
        "memory": ("Memory", trainer.memory_table),
    }
    for part in args.only:
        title, job = jobs[part]
        start = time.perf_counter()
        body = job()
        if part in ("seeds", "sweep", "memory"):
            body = f"Command: `python -m benchmarks.run --only {part}`. Hardware: " + (
                f"{results.hardware()}; jax {jax.__version__}.\n\n{body}"
            )
        results.write_section(title, body)
        print(f"[{part}] written in {time.perf_counter() - start:.0f} s", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
