"""D2C side by side with the baselines: same env, SAC, seeds; one table and one figure.

    python -m benchmarks.compare --env medium_maze --algos d2c,her,hgg --seeds 3 \\
        [--preset quick] [--seed 0] [--total-steps N] [--out DIR] [--report-only]

Each algorithm trains its N seeds as one vmapped program into DIR/<algo> (default DIR:
runs/compare-<env>-<preset>); an existing run directory is resumed, so a killed
comparison continues and a finished one is only reported. Then DIR/comparison.md gets
the table (final and best eval success, per mode, env steps to the first 0.8, the
paper's curriculum distance; mean ± std over seeds) and DIR/comparison.png the success
curves (mean ± std over seeds). `--report-only` tabulates the run directories as they
are, without training.
"""

from __future__ import annotations

import argparse
import pathlib
import sys

import numpy as np

from d2c_jax import config as config_lib
from d2c_jax.training import cli, loop
from d2c_jax.training import logging as logging_lib
from d2c_jax.viewing import plots

TARGET = 0.8  # issue 14's target: eval success >= 0.8


def _per_seed(rows: list[dict], key: str) -> tuple[np.ndarray, np.ndarray]:
    """(env steps (T,), values (T, seeds)) of the evaluation rows holding `key`."""
    rows = [r for r in rows if key in r]
    steps = np.array([r["env_steps"] for r in rows], np.float64)
    values = np.array([np.atleast_1d(r[key]) for r in rows], np.float64)
    return steps, values.reshape(len(rows), -1)


def first_reaching(steps: np.ndarray, values: np.ndarray, target: float) -> list[float | None]:
    """Per seed, the env steps of the first evaluation at or above `target` (None: never).

    steps (T,), values (T, seeds)."""
    out = []
    for seed_values in values.T:
        hits = np.flatnonzero(seed_values >= target)
        out.append(float(steps[hits[0]]) if hits.size else None)
    return out


def summarize(rows: list[dict]) -> dict:
    """One run directory's comparison row: per-seed arrays and the env steps trained.

    Raises:
      ValueError: no evaluation rows.
    """
    steps, success = _per_seed(rows, "eval/success")
    if not len(steps):
        raise ValueError("no evaluation rows (eval/success)")
    last = [r for r in rows if "eval/success" in r][-1]
    n_modes = sum(k.startswith("eval/success/") for k in last)
    return {
        "env_steps": int(steps[-1]),
        "final": success[-1],
        "best": success.max(axis=0),
        "final_per_mode": [np.atleast_1d(last[f"eval/success/{k}"]) for k in range(n_modes)],
        "to_target": first_reaching(steps, success, TARGET),
        "distance": np.atleast_1d(last["curriculum/distance"]),
    }


def _mean_std(x: np.ndarray) -> str:
    x = np.asarray(x, np.float64)
    return f"{x.mean():.2f}" if x.size == 1 else f"{x.mean():.2f} ± {x.std():.2f}"


def _steps_text(values: list[float | None]) -> str:
    reached = [v for v in values if v is not None]
    if not reached:
        return "never"
    text = f"{np.mean(reached) / 1e3:,.0f}k"
    return text if len(reached) == len(values) else f"{text} ({len(reached)}/{len(values)} seeds)"


def markdown_table(summaries: dict[str, dict]) -> str:
    """The comparison table: one row per algorithm (`summarize` outputs by algo name)."""
    n_modes = max(len(s["final_per_mode"]) for s in summaries.values())
    head = ["algo", "seeds", "env steps", "final eval", "best eval"]
    head += [f"final mode {k}" for k in range(n_modes)]
    head += [f"env steps to {TARGET}", "curriculum/distance"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for algo, s in summaries.items():
        cells = [algo, str(len(s["final"])), f"{s['env_steps']:,}"]
        cells += [_mean_std(s["final"]), _mean_std(s["best"])]
        cells += [_mean_std(m) for m in s["final_per_mode"]]
        cells += [_steps_text(s["to_target"]), _mean_std(s["distance"])]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="benchmarks.compare", description=__doc__.split("\n")[0])
    parser.add_argument("--env", required=True)
    parser.add_argument("--algos", default=",".join(config_lib.ALGO_NAMES))
    parser.add_argument("--seeds", type=int, default=1)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--preset", default="quick")
    parser.add_argument("--total-steps", type=int, default=None)
    parser.add_argument("--out", default=None)
    parser.add_argument("--report-only", action="store_true", help="tabulate, do not train")
    return parser


def _train(algo: str, args, run_dir: pathlib.Path) -> None:
    """Trains (or resumes) one algorithm's seeds into run_dir through the CLI's parser."""
    argv = ["--env", args.env, "--preset", args.preset, "--algo", algo]
    argv += ["--seed", str(args.seed), "--seeds", str(args.seeds)]
    if args.total_steps is not None:
        argv += ["--total-steps", str(args.total_steps)]
    cfg, _, _ = cli.parse_args(argv + ["--out", str(run_dir)])
    resume = (run_dir / "checkpoints").is_dir()
    status = loop.train(cfg, run_dir, resume=resume)
    if status:
        raise loop.RunError(f"{algo}: training stopped with status {status}", status)


def main(argv=None) -> int:
    args = _parser().parse_args(argv)
    algos = [a.strip() for a in args.algos.split(",") if a.strip()]
    unknown = [a for a in algos if a not in config_lib.ALGO_NAMES]
    if unknown or not algos:
        valid = ", ".join(config_lib.ALGO_NAMES)
        print(f"error: --algos {args.algos!r}: valid algos are {valid}", file=sys.stderr)
        return 2
    out = pathlib.Path(args.out or f"runs/compare-{args.env}-{args.preset}")
    summaries, curves = {}, []
    try:
        for algo in algos:
            run_dir = out / algo
            if not args.report_only:
                _train(algo, args, run_dir)
            rows = logging_lib.read_metrics(run_dir / "metrics.jsonl")
            summaries[algo] = summarize(rows)
            curves.append((run_dir, rows))
    except (cli.UsageError, loop.RunError, FileNotFoundError, ValueError) as err:
        print(f"error: {err}", file=sys.stderr)
        return getattr(err, "status", 2)
    table = markdown_table(summaries)
    (out / "comparison.md").write_text(table + "\n")
    plots.compare_runs(curves, out / "comparison.png")
    print(table)
    return 0


if __name__ == "__main__":
    sys.exit(main())
