"""Summarise a training run's learning curve: a plot and a markdown table.

    python -m benchmarks.learning_curve runs/medium_maze-quick-0 --out benchmarks/plots

Prints the evaluation rows (env steps, wall-clock, eval/success per mode), the first
evaluation at or above the target, and writes `<out>/<run name>_success.png`. With
`--window N`, also the training metrics averaged over windows of N env steps (train
success, still share, final distance, the paper's curriculum distance, Q, alpha, entropy)
and the median seconds per iteration: the diagnosis a missed target asks for.
"""

from __future__ import annotations

import argparse
import json
import pathlib
import sys

import numpy as np

from d2c_jax.training import logging as logging_lib
from d2c_jax.viewing import plots


def eval_rows(rows: list[dict]) -> list[dict]:
    """Rows that hold an evaluation."""
    return [r for r in rows if "eval/success" in r]


def first_at_or_above(rows: list[dict], target: float) -> dict | None:
    """The first evaluation row whose mean success (over seeds) reaches `target`."""
    for r in eval_rows(rows):
        if logging_lib.mean_of(r["eval/success"]) >= target:
            return r
    return None


def stays_above(rows: list[dict], target: float) -> dict | None:
    """The evaluation row from which every later evaluation reaches `target`, or None."""
    evals = eval_rows(rows)
    ok = np.array([logging_lib.mean_of(r["eval/success"]) >= target for r in evals])
    if not ok.size or not ok[-1]:
        return None
    below = np.flatnonzero(~ok)
    return evals[below[-1] + 1 if below.size else 0]


def markdown_table(rows: list[dict], every: int = 1) -> str:
    """Evaluation rows as a markdown table (every `every`-th row, and the last)."""
    evals = eval_rows(rows)
    picked = evals[::every] + ([evals[-1]] if evals and (len(evals) - 1) % every else [])
    modes = sorted(k for k in evals[0] if k.startswith("eval/success/")) if evals else []
    head = "| env steps | minutes | eval/success | " + " | ".join(m[5:] for m in modes) + " |"
    lines = [head, "|" + "---|" * (3 + len(modes))]
    for r in picked:
        cells = [
            f"{r['env_steps']:,}",
            f"{r['time/elapsed_s'] / 60:.1f}",
            f"{logging_lib.mean_of(r['eval/success']):.3f}",
        ]
        cells += [f"{logging_lib.mean_of(r[m]):.2f}" for m in modes]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


# (metrics key, column title) of `window_table`; a window's value is the mean over its rows
# that hold the key (curriculum/distance: its evaluation rows).
WINDOW_KEYS = (
    ("train/success_rate", "train success"),
    ("train/still_share", "still share"),
    ("train/final_distance", "final distance"),
    ("curriculum/distance", "curriculum/distance"),
    ("sac/q_mean", "Q"),
    ("sac/alpha", "alpha"),
    ("sac/entropy", "entropy"),
)


def window_table(rows: list[dict], window: int) -> str:
    """Markdown: per window of `window` env steps ((lo, hi], by each row's env_steps), the
    mean over seeds and rows of each WINDOW_KEYS metric and the median time/iteration_s."""
    windows: dict[int, list[dict]] = {}
    for r in rows:
        windows.setdefault((r["env_steps"] - 1) // window, []).append(r)
    head = "| env steps | " + " | ".join(t for _, t in WINDOW_KEYS) + " | s per iteration |"
    lines = [head, "|" + "---|" * (len(WINDOW_KEYS) + 2)]
    for w, in_window in sorted(windows.items()):
        lo, hi = w * window, (w + 1) * window
        cells = [f"{lo // 1000:,}-{hi // 1000:,}k" if window % 1000 == 0 else f"{lo:,}-{hi:,}"]
        for key, _ in WINDOW_KEYS:
            values = [logging_lib.mean_of(r[key]) for r in in_window if key in r]
            cells.append(f"{np.mean(values):.4g}" if values else "")
        seconds = [r["time/iteration_s"] for r in in_window if "time/iteration_s" in r]
        cells.append(f"{np.median(seconds):.1f}" if seconds else "")
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=pathlib.Path, help="run directory")
    parser.add_argument("--out", type=pathlib.Path, default=pathlib.Path("benchmarks/plots"))
    parser.add_argument("--target", type=float, default=0.8)
    parser.add_argument("--every", type=int, default=5, help="table: every n-th evaluation")
    parser.add_argument(
        "--window", type=int, default=0, metavar="N", help="training metrics per N env steps"
    )
    args = parser.parse_args(argv)
    rows = logging_lib.read_metrics(args.run / "metrics.jsonl")
    if args.window < 0:
        print(f"error: --window must be >= 0 env steps, got {args.window}", file=sys.stderr)
        return 2
    if not eval_rows(rows):
        print(f"error: {args.run} has no evaluation rows", file=sys.stderr)
        return 2
    cfg = json.loads((args.run / "config.json").read_text())
    n_modes = len([k for k in eval_rows(rows)[0] if k.startswith("eval/success/")])
    args.out.mkdir(parents=True, exist_ok=True)
    plot = args.out / f"{args.run.name}_success.png"
    plots.success_curve(rows, n_modes, plot)
    hit = first_at_or_above(rows, args.target)
    best = max(eval_rows(rows), key=lambda r: logging_lib.mean_of(r["eval/success"]))
    print(f"run {args.run} (env {cfg['env']}, preset {cfg['preset']})")
    if hit:
        print(
            f"first eval/success >= {args.target}: {logging_lib.mean_of(hit['eval/success']):.3f}"
            f" at {hit['env_steps']:,} env steps, {hit['time/elapsed_s'] / 60:.1f} min"
        )
    print(
        f"best: {logging_lib.mean_of(best['eval/success']):.3f} at {best['env_steps']:,} steps;"
        f" last: {logging_lib.mean_of(eval_rows(rows)[-1]['eval/success']):.3f}"
    )
    stays = stays_above(rows, args.target)
    if stays:
        print(
            f"every evaluation >= {args.target} from {stays['env_steps']:,} env steps "
            f"({stays['time/elapsed_s'] / 60:.1f} min) on"
        )
    print(markdown_table(rows, args.every))
    if args.window:
        print(window_table(rows, args.window))
    print(f"plot: {plot}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
