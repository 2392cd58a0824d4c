"""Where a maze run's agent has been, per layout cell, and what its classifier makes of it.

    python -m benchmarks.visit_map RUN_DIR [--seed-index 0] [--per-head]

Reads the run's newest checkpoint and prints three maps of the layout side by side:
log10 of the stored states in each cell (all of them, then the curriculum phase only:
s_0..s_walk_start of each episode), and 10 x p_pseudo at each cell centre, max over the
modes (0-9). `#` is a wall cell no state lies in, `.` a free cell none does, `m` a mode.
The frontier of exploration is where a digit meets a `.`; issue 10's diagnosis of
complex_maze and spiral_maze (benchmarks/RESULTS.md) was read from these maps.

`--per-head` adds, for each mode's conditioning goal g_k, each head's f_i(cell; g_k)
(10 x, 0-9): whether the heads disagree by goal or only by region (why spiral_maze's
curriculum is mode-agnostic, docs/DEVIATIONS.md).
"""

from __future__ import annotations

import argparse

import jax
import numpy as np

from envs import layouts


def cell_counts(layout, cell_size: float, points: np.ndarray) -> np.ndarray:
    """(rows, cols) number of the points (n, 2) lying in each cell of the layout."""
    rows, cols = layouts.points_to_cells(layout, points, cell_size)
    counts = np.zeros((len(layout), len(layout[0])), int)
    inside = (rows >= 0) & (rows < counts.shape[0]) & (cols >= 0) & (cols < counts.shape[1])
    np.add.at(counts, (rows[inside], cols[inside]), 1)
    return counts


def draw_counts(layout, counts: np.ndarray) -> list[str]:
    """One string per row: log10 of each count (capped at 9), `#`/`.` where zero."""
    return [
        "".join(
            str(min(9, int(np.log10(n)))) if n else ("#" if ch == "#" else ".")
            for ch, n in zip(row, counts_row, strict=True)
        )
        for row, counts_row in zip(layout, counts, strict=True)
    ]


def draw_scores(layout, scores: np.ndarray, modes: list[tuple[int, int]]) -> list[str]:
    """One string per row: 10 x score (0-9) per cell, `m` on the mode cells."""
    rows = [[str(min(9, int(10 * p))) for p in row] for row in scores]
    for r, c in modes:
        rows[r][c] = "m"
    return ["".join(row) for row in rows]


def cell_centres(layout, cell_size: float) -> np.ndarray:
    """(rows * cols, 2) world xy of every cell centre, row-major."""
    return np.stack(
        [
            layouts.cell_center(layout, (r, c), cell_size)
            for r in range(len(layout))
            for c in range(len(layout[0]))
        ]
    )


def head_maps(net, params, layout, cell_size: float, goal: np.ndarray) -> np.ndarray:
    """(n_heads, rows, cols): each head's f_i(cell centre; goal), goal (d,)."""
    from d2c_jax import classifier

    centres = cell_centres(layout, cell_size)
    goals = np.broadcast_to(np.asarray(goal, np.float32), centres.shape)
    probs = np.asarray(classifier.head_probs(net, params, centres, goals))  # (n, heads)
    return probs.T.reshape(-1, len(layout), len(layout[0]))


def main(argv=None) -> int:
    from d2c_jax import classifier, render, trainer

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run")
    parser.add_argument("--seed-index", type=int, default=0)
    parser.add_argument("--per-head", action="store_true", help="each head's map per mode")
    args = parser.parse_args(argv)
    cfg, env, ts = render.load_run(args.run)
    layout, size = env.layout, env.cell_size
    rp = jax.tree.map(lambda x: np.asarray(x[args.seed_index]), ts.replay)
    ag = rp.achieved_goal[: int(rp.size)]  # (episodes, H + 1, 2)
    phase = np.arange(ag.shape[1])[None] <= rp.walk_start[: int(rp.size), None]
    every = cell_counts(layout, size, ag.reshape(-1, 2))
    curriculum_phase = cell_counts(layout, size, ag[phase])
    centres = cell_centres(layout, size)
    net = trainer.make_components(cfg, env).classifier_net
    params = jax.tree.map(lambda x: x[args.seed_index], ts.classifier.params)
    p = classifier.p_pseudo(net, params, centres[:, None], np.asarray(env.goal_points)[None])
    scores = np.asarray(p).max(axis=-1).reshape(len(layout), len(layout[0]))
    modes = [layouts.point_to_cell(layout, g, size) for g in env.goal_points]
    print(f"{args.run}: {ag.shape[0]} episodes, {int(ts.env_steps[args.seed_index]):,} env steps")
    print("visits (log10)   curriculum phase   10 x p_pseudo")
    maps = zip(
        draw_counts(layout, every),
        draw_counts(layout, curriculum_phase),
        draw_scores(layout, scores, modes),
        strict=True,
    )
    for a, b, c in maps:
        print(f"{a}   {b}   {c}")
    if args.per_head:
        for k, goal in enumerate(env.goal_points):
            heads = head_maps(net, params, layout, size, goal)
            print(f"mode {k} at {tuple(float(v) for v in goal)}: 10 x f_i(cell; g_{k})")
            print("   ".join(f"head {i}".ljust(len(layout[0])) for i in range(len(heads))))
            drawn = [draw_scores(layout, h, modes) for h in heads]
            for row in zip(*drawn, strict=True):
                print("   ".join(row))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
