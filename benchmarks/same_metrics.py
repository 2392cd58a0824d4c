"""Whether a run's metrics equal a reference's, row by row, apart from wall-clock keys.

    python -m benchmarks.same_metrics RUN REFERENCE

RUN and REFERENCE are each a run directory (its metrics.jsonl) or a metrics file
(`.jsonl`, or `.jsonl.gz` as `benchmarks/runs/` stores them). The rows of the iterations
both hold are compared on every key but `time/*`. It prints "identical: N rows
(iterations A-B)" and exits 0, or names the first iteration that differs and its keys and
exits 1; a missing or unreadable file exits 2. It checks the project's determinism
promise (the same seed gives the same result on CPU) across machines and sessions: a
run started again from scratch against the stored metrics of an earlier one, or a
resumed run against an uninterrupted one.
"""

from __future__ import annotations

import argparse
import gzip
import json
import pathlib
import sys


class MetricsError(Exception):
    """A metrics file that is missing or not JSON lines."""


def load_rows(path) -> list[dict]:
    """The rows of a metrics file, a gzipped one, or a run directory's metrics.jsonl."""
    path = pathlib.Path(path)
    if path.is_dir():
        path = path / "metrics.jsonl"
    if not path.is_file():
        raise MetricsError(f"no metrics file at {path}")
    opener = gzip.open if path.suffix == ".gz" else open
    try:
        with opener(path, "rt") as f:
            return [json.loads(line) for line in f if line.strip()]
    except (OSError, ValueError) as err:
        raise MetricsError(f"{path} is not a metrics file: {err}") from err


def _without_time(row: dict) -> dict:
    return {k: v for k, v in row.items() if not k.startswith("time/")}


def compare(rows: list[dict], reference: list[dict]) -> tuple[list[int], int | None, list[str]]:
    """(the iterations both hold, in order; the first of them whose rows differ outside
    `time/*`, or None; that row's differing keys, sorted, a key missing on one side
    included)."""
    by_iteration = {r["iteration"]: _without_time(r) for r in reference}
    common = [r["iteration"] for r in rows if r["iteration"] in by_iteration]
    for row in rows:
        ref = by_iteration.get(row["iteration"])
        if ref is None:
            continue
        mine = _without_time(row)
        keys = sorted(k for k in mine.keys() | ref.keys() if mine.get(k) != ref.get(k))
        if keys:
            return common, row["iteration"], keys
    return common, None, []


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run")
    parser.add_argument("reference")
    args = parser.parse_args(argv)
    try:
        rows, reference = load_rows(args.run), load_rows(args.reference)
    except MetricsError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    common, iteration, keys = compare(rows, reference)
    if not common:
        print(f"error: no iteration in common between {args.run} and {args.reference}",
              file=sys.stderr)  # fmt: skip
        return 2
    if iteration is not None:
        shown = ", ".join(keys[:8]) + (f" and {len(keys) - 8} more" if len(keys) > 8 else "")
        print(f"differ: iteration {iteration} ({len(keys)} keys: {shown})")
        return 1
    print(f"identical: {len(common)} rows (iterations {common[0]}-{common[-1]})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
