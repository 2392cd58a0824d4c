"""Regenerates benchmarks/RESULTS.md: every comparison, each measured in this one run.

    pip install -e '.[bench]'      # the reference tools: SB3, gymnasium-robotics, PyTorch
    python -m benchmarks.run [--only throughput sac_update envs matching seeds sweep memory]

Sections written (each names its command and the hardware):
  "Training throughput vs SB3"  d2c_jax SAC+HER and D2C against SB3 SAC+HER (benchmarks.sb3)
  "SAC update"                  d2c_jax against PyTorch, against the CPU roofline
  "Environments"                MJX at batch 1/64/1024 against C MuJoCo (benchmarks.envs)
  "Matching"                    the auction against scipy and optax (benchmarks.matching)
  "Seed scaling", "Memory"      benchmarks.trainer
The "Learning" section comes from training runs (benchmarks.learning_curve), not from here.
"""

from __future__ import annotations

import argparse
import time

import jax

from benchmarks import envs as envs_bench
from benchmarks import matching, results, sac_update, sb3, trainer
from envs import ENV_NAMES

PARTS = ("throughput", "sac_update", "envs", "matching", "seeds", "sweep", "memory")
TARGET_VS_SB3 = {"paper": 1.4, "small": 2.5}
"""Issue targets: d2c_jax SAC+HER env steps/s over SB3's at identical settings."""


def throughput_section() -> str:
    ours = trainer.throughput_rows()
    rows = [
        "| size (hidden, batch) | tool | env steps/s | vs SB3 | target |",
        "|---|---|---|---|---|",
    ]
    for size in TARGET_VS_SB3:
        label = sac_update.size_label(size)
        reference = sb3.sb3_env_steps_per_s(size)
        rows.append(f"| {label} | SB3 SAC+HER (PyTorch) | {reference:,.1f} | 1.00x | |")
        for variant in ("SAC+HER", "D2C"):
            rate = ours[size, variant]
            target = f">= {TARGET_VS_SB3[size]}x" if variant == "SAC+HER" else ""
            ratio = rate / reference
            rows.append(f"| {label} | d2c_jax {variant} | {rate:,.1f} | {ratio:.2f}x | {target} |")
        print("\n".join(rows[-3:]), flush=True)
    return "\n".join(
        [
            f"Command: `python -m benchmarks.run --only throughput` ({time.strftime('%Y-%m-%d')}).",
            f"Hardware: {results.hardware()}; jax {jax.__version__}.",
            "SB3 on gymnasium-robotics `PointMaze_Medium-v3` (C MuJoCo, 1 env); d2c_jax on "
            "`medium_maze` (4 envs per iteration, one compiled program). Identical settings: "
            "the same network sizes, batch, one gradient step per env step, actor and target "
            "every step. d2c_jax SAC+HER = D2C with sparse reward, goals from the desired "
            "set and no classifier updates; D2C adds the classifier (16 updates per 2,000 "
            "env steps), the matching curriculum and the intrinsic reward.",
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
    args = parser.parse_args(argv)
    jobs = {
        "throughput": ("Training throughput vs SB3", throughput_section),
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
