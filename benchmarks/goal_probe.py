"""Train on an env whose goal points are moved: a diagnostic, never a task result.

    python -m benchmarks.goal_probe "X,Y[,Z];X,Y[,Z]..." -- TRAIN.PY ARGUMENTS

The points replace `env.goal_points` for the whole run (the desired examples, the
curriculum's slots and the evaluation goals), so `eval/success` reads whether the method
learns to reach *those* points. With points a cell or two from the start it separates
"can the agent learn to walk to a goal at all" from "does the curriculum bring it to the
modes" (benchmarks/RESULTS.md, "The Ant stands still for goals past its frontier"). The
run directory gets the points in `goal_probe.json` when train.py returns (a run it
resumes is given the same points again on the command line); tools that rebuild the env from
config.json (`d2c_jax.evaluate`, `benchmarks.visit_map`) see the env's own modes.
"""

from __future__ import annotations

import json
import sys

import numpy as np

import envs

PROBE_FILE = "goal_probe.json"


def parse_points(text: str) -> np.ndarray:
    """(n, d) float32 from "x,y;x,y" (';' between points, ',' between coordinates).

    Raises:
      ValueError: empty, non-numeric or ragged input.
    """
    try:
        rows = [[float(v) for v in point.split(",")] for point in text.split(";")]
    except ValueError:
        raise ValueError(f'goal points must be numbers as "x,y;x,y", got {text!r}') from None
    if not rows or len({len(r) for r in rows}) != 1 or not np.isfinite(rows).all():
        raise ValueError(f"goal points must be finite and all of one length, got {text!r}")
    return np.asarray(rows, np.float32)


def moved_make(points: np.ndarray, make=envs.make):
    """`envs.make` with the built env's `goal_points` replaced by `points`.

    Raises (from the returned function):
      ValueError: the points' dimension is not the env's goal dimension.
    """

    def make_moved(name: str, **overrides):
        env = make(name, **overrides)
        if points.shape[1] != env.goal_dim:
            raise ValueError(
                f"goal points must have {env.goal_dim} coordinates for {name}, "
                f"got {points.shape[1]}"
            )
        env.goal_points = points
        return env

    return make_moved


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if len(argv) < 2 or argv[1] != "--":
        print('error: usage: python -m benchmarks.goal_probe "x,y;x,y" -- TRAIN ARGS',
              file=sys.stderr)  # fmt: skip
        return 2
    try:
        points = parse_points(argv[0])
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    from d2c_jax.training import cli

    train_args = argv[2:]
    envs.make = moved_make(points)  # the trainer builds its env through envs.make
    print(f"goal probe: goal points moved to {points.tolist()} (a diagnostic, not the task)")
    try:
        status = cli.main(train_args)
    except ValueError as err:  # the points' dimension against the env's
        print(f"error: {err}", file=sys.stderr)
        return 2
    try:  # the run directory the CLI resolved, its default included
        out = cli.parse_args(train_args)[1]
    except cli.UsageError:  # bad train.py input: main has said so and returned 2
        return status
    if out.is_dir():
        (out / PROBE_FILE).write_text(json.dumps({"goal_points": points.tolist()}) + "\n")
    return status


if __name__ == "__main__":
    raise SystemExit(main())
