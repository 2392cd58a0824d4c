"""Where a run's agent has been, per cell, and what its classifier makes of it.

    python -m benchmarks.visit_map RUN_DIR [--seed-index 0] [--per-head] [--her-goals]
        [--reach N] [--rematch BETA [BETA ...]]

Reads the run's newest checkpoint and prints three maps side by side, over the maze's
layout (mazes, Ant) or the table cut into 0.1 squares seen from above (Sawyer; scored at
the modes' height):
log10 of the stored states in each cell (all of them, then the curriculum phase only:
s_0..s_walk_start of each episode), and 10 x p_pseudo at each cell centre, max over the
modes (0-9). `#` is a wall cell no state lies in, `.` a free cell none does, `m` a mode.
The frontier of exploration is where a digit meets a `.`; issue 10's diagnosis of
complex_maze and spiral_maze (benchmarks/RESULTS.md) was read from these maps.

`--per-head` adds, for each mode's conditioning goal g_k, each head's f_i(cell; g_k)
(10 x, 0-9): whether the heads disagree by goal or only by region (why spiral_maze's
curriculum is mode-agnostic, docs/DEVIATIONS.md).

`--her-goals` adds where HER's "future" goals land for the transitions that start in
their episode's start cell (log10 of the expected number per 10^6 of them): the goals the
critic learns values for at the start, so a cell with none is one whose value cannot flow
back to s_0 (benchmarks/RESULTS.md, stop 64: 73% of the Ant's stored transitions lie near
its start, and ten times fewer of their goals lie at its frontier than before it).

`--reach N` adds where the policy can go: for each free cell, the share of N episodes
from the start state (SPEC §7's evaluation: deterministic actor, no goal switching,
success within the radius at any step) that reach that cell's centre as the goal
(10 x, 0-9; `A` = every episode), and the share of them whose achieved goal never
leaves the success radius around its start (the policy stands still for that goal). Set
beside the visits, it tells cells the agent has been to from cells its goal-conditioned
policy can reach on demand, and the goals it does not even try for.

`--rematch BETA ...` runs the checkpoint's curriculum matching (SPEC §5) again with the
goal-value weight set to each BETA (`curriculum.goal_value_weight`, 0 = SPEC's cost) and
draws where the K curriculum goals land, one map per mode that the slots serve (slot j
serves mode j mod n_modes): the number of goals in each cell (`+` for 10 or more), and
the paper's `curriculum/distance`. Three matchings per BETA (different noise keys). It
asks whether a curriculum sends each mode's slots towards that mode or, as on the Ant
(benchmarks/RESULTS.md, stop 68), the slots of every mode to the newest frontier.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from typing import NamedTuple

import jax
import numpy as np

from envs import layouts


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


class Grid(NamedTuple):
    """Cells to count and score on: a maze's layout, or a table cut into squares."""

    layout: tuple[str, ...]  # rows of '#' (wall or obstacle) and '.' cells, +y first
    centres: np.ndarray  # (rows * cols, goal_dim) goal-space point scored in each cell
    cell_of: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]  # xy (n, 2) -> rows, cols


def layout_grid(layout, cell_size: float) -> Grid:
    """A maze's own cells (2-d goals)."""
    centres = np.stack(
        [
            layouts.cell_center(layout, (r, c), cell_size)
            for r in range(len(layout))
            for c in range(len(layout[0]))
        ]
    )
    return Grid(tuple(layout), centres, lambda xy: layouts.points_to_cells(layout, xy, cell_size))


def table_grid(env, cell: float = 0.1) -> Grid:
    """Squares of `cell` over the goal bounds' xy, scored at the modes' mean height; a
    square whose centre lies in one of `env.obstacles_xy` is drawn '#'."""
    low, high = np.asarray(env.goal_low[:2], np.float64), np.asarray(env.goal_high[:2])
    n_cols, n_rows = np.round((high - low) / cell).astype(int)
    xs = low[0] + (np.arange(n_cols) + 0.5) * cell
    ys = high[1] - (np.arange(n_rows) + 0.5) * cell
    xy = np.stack(np.meshgrid(xs, ys), axis=-1).reshape(-1, 2)  # row-major, +y first
    z = np.asarray(env.goal_points)[:, 2:].mean(axis=0)
    centres = np.concatenate([xy, np.broadcast_to(z, (len(xy), len(z)))], axis=-1)
    blocked = np.zeros(len(xy), bool)
    for centre, half in zip(*getattr(env, "obstacles_xy", ((), ())), strict=True):
        blocked |= np.all(np.abs(xy - centre) <= half, axis=-1)
    layout = tuple(
        "".join("#" if b else "." for b in row) for row in blocked.reshape(n_rows, n_cols)
    )

    def cell_of(points):
        cols = np.floor((points[:, 0] - low[0]) / cell).astype(int)
        rows = np.floor((high[1] - points[:, 1]) / cell).astype(int)
        return rows, cols

    return Grid(layout, centres.astype(np.float32), cell_of)


def env_grid(env) -> Grid:
    """The maze's layout if the env has one, else its table in 0.1 squares."""
    if hasattr(env, "layout"):
        return layout_grid(env.layout, env.cell_size)
    return table_grid(env)


def flat_cells(grid: Grid, points: np.ndarray) -> np.ndarray:
    """(n,) row-major index of the cell each point (n, >= 2) lies in; -1 off the grid."""
    n_rows, n_cols = len(grid.layout), len(grid.layout[0])
    rows, cols = grid.cell_of(np.asarray(points, np.float64)[:, :2])
    inside = (rows >= 0) & (rows < n_rows) & (cols >= 0) & (cols < n_cols)
    return np.where(inside, rows * n_cols + cols, -1)


def grid_counts(grid: Grid, points: np.ndarray) -> np.ndarray:
    """(rows, cols) number of the points (n, >= 2) lying in each cell of the grid."""
    n_rows, n_cols = len(grid.layout), len(grid.layout[0])
    cells = flat_cells(grid, points)
    return np.bincount(cells[cells >= 0], minlength=n_rows * n_cols).reshape(n_rows, n_cols)


def head_maps(net, params, grid: Grid, goal: np.ndarray) -> np.ndarray:
    """(n_heads, rows, cols): each head's f_i(cell centre; goal), goal (d,)."""
    from d2c_jax.curricula import classifier

    goals = np.broadcast_to(np.asarray(goal, np.float32), grid.centres.shape)
    probs = np.asarray(classifier.head_probs(net, params, grid.centres, goals))  # (n, heads)
    return probs.T.reshape(-1, len(grid.layout), len(grid.layout[0]))


def reach_rates(env, policy, grid: Grid, episodes: int, key) -> tuple[np.ndarray, np.ndarray]:
    """Per free cell, with its centre as the goal, over `episodes` deterministic episodes
    (SPEC §7's: from the start state with its reset noise, no goal switching): the share
    that reach it, and the share that never leave the success radius around their start
    (`rollout.stayed_at_start`: the policy stands still for that goal). Both
    (rows, cols), NaN on '#' cells.

    Args:
      env: the environment; policy: a `rollout.Policy` (pass the deterministic actor).
      grid: its cells (`env_grid`); episodes: episodes per cell; key: PRNG key (reset noise).
    """
    from d2c_jax.core import rollout

    free = np.array([ch != "#" for row in grid.layout for ch in row])
    goals = np.repeat(grid.centres[free].astype(np.float32), episodes, axis=0)

    def play(g, k):
        record = lambda before, action, after: (after.success, after.achieved_goal)  # noqa: E731
        first, (success, achieved) = rollout.run(env, policy, g, k, record=record)
        path = jax.numpy.concatenate([first.achieved_goal[:, None], achieved], axis=1)
        return success.any(axis=1), rollout.stayed_at_start(path, env.success_radius)

    hit, still = (np.asarray(x, np.float64) for x in jax.jit(play)(goals, key))
    shape = (len(grid.layout), len(grid.layout[0]))
    per_cell = []
    for flags in (hit, still):
        rates = np.full(free.shape, np.nan)
        rates[free] = flags.reshape(-1, episodes).mean(axis=1)
        per_cell.append(rates.reshape(shape))
    return per_cell[0], per_cell[1]


def her_goals_from_start(
    grid: Grid, achieved: np.ndarray, relabel_prob: float, min_distance: float, chunk: int = 16
) -> np.ndarray:
    """(rows, cols): where HER's "future" goals land for the stored transitions that
    start in their episode's start cell, as the expected number per such transition
    (exact, not sampled; every stored transition weighs the same, whatever share of the
    batches its phase gets). These are the goals the critic learns about at the start: a goal cell
    with none is one whose value cannot flow back to s_0.

    For transition t of an episode of horizon H, `her.sample_relabelled` takes
    phi(s_t') with t' uniform in [t + 1, H] with probability `relabel_prob`, unless it
    lies within `min_distance` of phi(s_t); so each t' weighs relabel_prob / (H - t)
    when it moved that far, else nothing (the own goal is kept; HER's "random" share,
    if any, is left out).

    Args:
      grid: the cells (`env_grid`).
      achieved: (episodes, H + 1, goal_dim) stored achieved goals phi(s_0..s_H).
      relabel_prob: `HERConfig.relabel_prob`; min_distance: `her.min_future_radii` x
        the success radius.
      chunk: episodes per vectorised block (memory: chunk x H x (H + 1) floats).
    """
    n_rows, n_cols = len(grid.layout), len(grid.layout[0])
    episodes, horizon = achieved.shape[0], achieved.shape[1] - 1
    cell = flat_cells(grid, achieved.reshape(-1, achieved.shape[-1])).reshape(episodes, -1)
    from_start = (cell[:, :horizon] == cell[:, :1]) & (cell[:, :1] >= 0)  # (E, H)
    t = np.arange(horizon)[:, None]
    later = (np.arange(horizon + 1)[None] > t) / (horizon - t)  # (H, H + 1) weight of t'
    totals = np.zeros(n_rows * n_cols + 1)  # the last slot collects off-grid goals
    for lo in range(0, episodes, chunk):
        a = np.asarray(achieved[lo : lo + chunk], np.float64)
        gap = np.linalg.norm(a[:, None, :, :] - a[:, :horizon, None, :], axis=-1)
        used = (gap > min_distance) | (min_distance <= 0)  # her.py filters only when > 0
        weight = relabel_prob * later[None] * used  # (e, H, H + 1)
        per_target = (weight * from_start[lo : lo + chunk, :, None]).sum(axis=1)  # (e, H + 1)
        np.add.at(totals, cell[lo : lo + chunk], per_target)
    return (totals[:-1] / max(int(from_start.sum()), 1)).reshape(n_rows, n_cols)


def draw_goal_counts(layout, counts: np.ndarray) -> list[str]:
    """One string per row: the number of goals per cell (1-9, `+` for 10 or more), the
    layout's `#` or `.` where none lies."""
    return [
        "".join(
            ("+" if n >= 10 else str(n)) if n else ch for ch, n in zip(row, counts_row, strict=True)
        )
        for row, counts_row in zip(layout, counts, strict=True)
    ]


def goal_counts_per_mode(grid: Grid, goals: np.ndarray, n_modes: int) -> list[np.ndarray]:
    """Per mode k, (rows, cols) counts of the goals (K, d) of the slots j = k mod n_modes
    (SPEC §5: slot j holds a desired example of mode j mod n_modes)."""
    return [grid_counts(grid, goals[k::n_modes]) for k in range(n_modes)]


def rematch(cfg, env, ts, goal_value_weight: float, keys) -> list[tuple[np.ndarray, float]]:
    """The curriculum of checkpoint `ts` matched again with `goal_value_weight` as beta,
    once per key: [(goals (K, d), curriculum/distance)]. Only beta changes (in the config,
    so that the program computes the value term, and in the run's traced hyperparameters,
    whose other values stay the run's own); the pool, the classifier and the critic are
    the checkpoint's."""
    import dataclasses

    import jax.numpy as jnp

    from d2c_jax.training import agent as agent_lib

    curriculum = dataclasses.replace(cfg.curriculum, goal_value_weight=goal_value_weight)
    agent = agent_lib.Agent(dataclasses.replace(cfg, curriculum=curriculum), env)
    hp = ts.hparams.replace(
        curriculum=ts.hparams.curriculum.replace(goal_value_weight=jnp.float32(goal_value_weight))
    )
    match, ts = jax.jit(agent.match), ts.replace(hparams=hp)
    out = []
    for key in keys:
        goals, metrics, _ = match(ts, key)
        out.append((np.asarray(goals), float(metrics["curriculum/distance"])))
    return out


def draw_reach(rates: np.ndarray) -> list[str]:
    """One string per row: 10 x rate (0-9), `A` where every episode reached, `#` at NaN."""
    return [
        "".join("#" if np.isnan(p) else "A" if p >= 1.0 else str(int(10 * p)) for p in row)
        for row in rates
    ]


def _parser():
    from benchmarks import run_args

    parser = run_args.probe_parser(__doc__)
    parser.add_argument("--per-head", action="store_true", help="each head's map per mode")
    parser.add_argument(
        "--her-goals",
        action="store_true",
        help="where HER's future goals land for the transitions that start in the start cell",
    )
    parser.add_argument(
        "--reach", type=int, default=0, metavar="N", help="reach map, N episodes per cell"
    )
    parser.add_argument(
        "--rematch",
        type=float,
        nargs="+",
        default=[],
        metavar="BETA",
        help="match the curriculum again with each goal-value weight; goals per cell and mode",
    )
    return parser


def _print_side_by_side(*maps: list[str]) -> None:
    """Rows of equally tall maps, printed next to each other."""
    for row in zip(*maps, strict=True):
        print("   ".join(row))


def _print_visits_and_scores(run, env, ts, grid, ag, every, net, modes) -> None:
    """Visits, curriculum-phase visits and 10 x max_k p_pseudo(cell; g_k), side by side."""
    from d2c_jax.curricula import classifier

    layout = grid.layout
    walk_start = np.asarray(ts.replay.walk_start)[: ag.shape[0]]  # (episodes,)
    phase = np.arange(ag.shape[1])[None] <= walk_start[:, None]
    goal_points = np.asarray(env.goal_points)
    p = classifier.p_pseudo(net, ts.classifier.params, grid.centres[:, None], goal_points[None])
    scores = np.asarray(p).max(axis=-1).reshape(len(layout), len(layout[0]))
    print(f"{run}: {ag.shape[0]} episodes, {int(ts.env_steps):,} env steps")
    print("visits (log10)   curriculum phase   10 x p_pseudo")
    _print_side_by_side(
        draw_counts(layout, every),
        draw_counts(layout, grid_counts(grid, ag[phase])),
        draw_scores(layout, scores, modes),
    )


def _print_heads(env, ts, grid, net, modes) -> None:
    """Each head's map per mode (--per-head)."""
    layout = grid.layout
    for k, goal in enumerate(np.asarray(env.goal_points)):
        heads = head_maps(net, ts.classifier.params, grid, goal)
        print(f"mode {k} at {tuple(round(float(v), 3) for v in goal)}: 10 x f_i(cell; g_{k})")
        print("   ".join(f"head {i}".ljust(len(layout[0])) for i in range(len(heads))))
        _print_side_by_side(*(draw_scores(layout, h, modes) for h in heads))


def _print_her_goals(cfg, env, grid, ag, every) -> None:
    """Where HER's future goals land for transitions starting in the start cell (--her-goals)."""
    min_distance = cfg.her.min_future_radii * env.success_radius
    per_start = her_goals_from_start(grid, ag, cfg.her.relabel_prob, min_distance)
    print(
        "HER future goals per 10^6 transitions that start in their episode's start "
        "cell (log10), visits (log10)"
    )
    _print_side_by_side(
        draw_counts(grid.layout, np.floor(1e6 * per_start)), draw_counts(grid.layout, every)
    )


def _print_reach(cfg, env, ts, grid, every, episodes: int, seed_index: int) -> None:
    """Reach and standing-still shares with each cell as the goal (--reach N)."""
    from d2c_jax.training import agent as agent_lib

    policy = agent_lib.Agent(cfg, env).policy(ts.sac, deterministic=True)
    rates, still = reach_rates(env, policy, grid, episodes, jax.random.key(seed_index))
    print(
        f"10 x reach rate, 10 x share standing still ({episodes} deterministic "
        "episodes per cell as the goal), visits (log10)"
    )
    _print_side_by_side(draw_reach(rates), draw_reach(still), draw_counts(grid.layout, every))


def _print_rematches(cfg, env, ts, grid, betas, seed_index: int) -> None:
    """Goals per cell and mode of the curriculum matched again with each beta (--rematch)."""
    keys = jax.random.split(jax.random.key(seed_index), 3)  # the same for every beta
    for beta in betas:
        for goals, distance in rematch(cfg, env, ts, beta, keys):
            per_mode = goal_counts_per_mode(grid, goals, env.n_modes)
            print(
                f"goals per cell, re-matched with beta {beta:g}, one map per mode "
                f"(curriculum/distance {distance:.2f})"
            )
            _print_side_by_side(*(draw_goal_counts(grid.layout, c) for c in per_mode))


def main(argv=None) -> int:
    from d2c_jax.curricula import classifier
    from d2c_jax.training import runs

    args = _parser().parse_args(argv)
    try:
        if args.reach < 0:
            raise runs.RunError(f"--reach must be >= 0 episodes per cell, got {args.reach}", 2)
        cfg, env, ts = runs.load_one_run(args.run, args.seed_index)
        if args.rematch and cfg.algo != "d2c":
            raise runs.RunError(f"--rematch needs a D2C run; {args.run} is --algo {cfg.algo}", 2)
    except runs.RunError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    grid = env_grid(env)
    ag = np.asarray(ts.replay.achieved_goal)[: int(ts.replay.size)]  # (episodes, H + 1, d)
    every = grid_counts(grid, ag.reshape(-1, ag.shape[-1]))
    net = classifier.make_classifier(cfg.classifier, env)
    mode_rows, mode_cols = grid.cell_of(np.asarray(env.goal_points)[:, :2].astype(np.float64))
    modes = list(zip(mode_rows.tolist(), mode_cols.tolist(), strict=True))
    _print_visits_and_scores(args.run, env, ts, grid, ag, every, net, modes)
    if args.per_head:
        _print_heads(env, ts, grid, net, modes)
    if args.her_goals:
        _print_her_goals(cfg, env, grid, ag, every)
    if args.reach:
        _print_reach(cfg, env, ts, grid, every, args.reach, args.seed_index)
    _print_rematches(cfg, env, ts, grid, args.rematch, args.seed_index)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
