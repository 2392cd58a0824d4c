"""metrics.jsonl writing and reading (host side).

One JSON object per logged iteration, flushed as it is written. Values are plain
numbers; with vmapped seeds every per-seed value is a list with one entry per seed.
"""

from __future__ import annotations

import json
import math
import pathlib
from typing import Any

import numpy as np


def to_jsonable(value: Any) -> Any:
    """numpy/jax scalars and arrays to floats, ints, bools and nested lists."""
    arr = np.asarray(value)
    if arr.dtype == bool:
        return arr.tolist()
    if np.issubdtype(arr.dtype, np.integer):
        return arr.tolist()
    return np.asarray(arr, np.float64).tolist()


def read_metrics(path: str | pathlib.Path) -> list[dict]:
    """All rows of a metrics.jsonl file."""
    path = pathlib.Path(path)
    if not path.exists():
        return []
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


class MetricsWriter:
    """Appends rows to metrics.jsonl, flushing each one."""

    def __init__(self, path: str | pathlib.Path):
        self.path = pathlib.Path(path)
        self._file = self.path.open("a")

    def write(self, row: dict) -> None:
        """Writes one row (values converted by `to_jsonable`)."""
        clean = {k: to_jsonable(v) for k, v in row.items()}
        self._file.write(json.dumps(clean, allow_nan=True) + "\n")
        self._file.flush()

    def close(self) -> None:
        self._file.close()

    def __enter__(self) -> MetricsWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def truncate_metrics(
    path: str | pathlib.Path, last_iteration: int, strip_last: tuple[str, ...] = ()
) -> int:
    """Drops rows beyond `last_iteration` (for --resume); returns the rows kept.

    Keys of the row at `last_iteration` that start with a prefix in `strip_last` are
    removed too.
    """
    path = pathlib.Path(path)
    rows = [r for r in read_metrics(path) if r["iteration"] <= last_iteration]
    if rows and rows[-1]["iteration"] == last_iteration and strip_last:
        rows[-1] = {k: v for k, v in rows[-1].items() if not k.startswith(strip_last)}
    tmp = path.with_suffix(".jsonl.tmp")
    tmp.write_text("".join(json.dumps(r) + "\n" for r in rows))
    tmp.replace(path)  # atomic on POSIX
    return len(rows)


def first_non_finite(metrics: dict) -> str | None:
    """Name of the first metric holding a NaN or inf, else None."""
    for name, value in metrics.items():
        arr = np.asarray(value)
        if np.issubdtype(arr.dtype, np.floating) and not np.isfinite(arr).all():
            return name
    return None


def mean_of(value) -> float:
    """Mean over seeds of a scalar or per-seed list (nan if empty)."""
    arr = np.asarray(value, np.float64)
    return float(arr.mean()) if arr.size else math.nan
