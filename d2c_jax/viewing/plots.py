"""Host-side matplotlib drawings: maps with walls, goal points, points and trajectories.

The trainer uses these for curriculum pictures (paper Fig. 8); the demo for random
rollouts. Nothing here runs inside jit.
"""

from __future__ import annotations

from collections.abc import Sequence

import matplotlib

matplotlib.use("Agg")  # headless: files only

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.patches import Circle, Rectangle  # noqa: E402


def draw_map(ax, env, show_goals: bool = True) -> None:
    """Draws an env's map on `ax`: wall cells (for layout envs), bounds and goal points.

    Args:
      ax: a matplotlib Axes.
      env: a GoalEnv; if it has `layout` and `cell_size`, every wall cell is drawn, else
        its bounds and its `obstacles_xy` boxes ((n, 2) centres, (n, 2) half-sizes), if any.
      show_goals: draw the mode points with their success radius.
    """
    low, high = np.asarray(env.goal_low)[:2], np.asarray(env.goal_high)[:2]
    if hasattr(env, "layout"):
        from envs import layouts

        half = env.cell_size / 2.0
        for x, y in layouts.wall_centers(env.layout, env.cell_size):
            ax.add_patch(Rectangle((x - half, y - half), 2 * half, 2 * half, color="0.35", lw=0))
        margin = env.cell_size
    else:
        ax.add_patch(Rectangle(low, *(high - low), fill=False, ec="0.35", lw=1.5))
        for (x, y), (hx, hy) in zip(*getattr(env, "obstacles_xy", ((), ())), strict=True):
            ax.add_patch(Rectangle((x - hx, y - hy), 2 * hx, 2 * hy, color="0.35", lw=0))
        margin = 0.05 * float(np.max(high - low))
    if show_goals:
        for k, g in enumerate(np.asarray(env.goal_points)):
            ax.add_patch(Circle(g[:2], env.success_radius, color="tab:red", alpha=0.5, lw=0))
            ax.plot(*g[:2], marker="*", ms=12, color="tab:red", mec="k", mew=0.5)
            ax.annotate(str(k), g[:2], xytext=(4, 4), textcoords="offset points", fontsize=8)
    ax.set_xlim(low[0] - margin, high[0] + margin)
    ax.set_ylim(low[1] - margin, high[1] + margin)
    ax.set_aspect("equal")
    ax.set_xticks([])
    ax.set_yticks([])


def draw_trajectories(ax, trajectories, color=None, alpha: float = 0.6) -> None:
    """Draws xy trajectories (n, T, >=2) as lines with a dot at each end point."""
    for traj in np.asarray(trajectories):
        ax.plot(traj[:, 0], traj[:, 1], lw=0.8, alpha=alpha, color=color)
        ax.plot(traj[-1, 0], traj[-1, 1], ".", ms=4, alpha=alpha, color=color)


def draw_points(ax, points, color="tab:blue", size: float = 12.0, label: str | None = None):
    """Draws xy points (n, >=2) as a scatter."""
    points = np.asarray(points).reshape(-1, np.asarray(points).shape[-1])
    ax.scatter(points[:, 0], points[:, 1], s=size, color=color, label=label, zorder=3)


def map_figure(envs_and_titles: Sequence[tuple[object, str]], panel_size: float = 4.0):
    """A row of map panels, one per (env, title); returns (fig, axes)."""
    n = len(envs_and_titles)
    fig, axes = plt.subplots(1, n, figsize=(panel_size * n, panel_size), squeeze=False)
    for ax, (env, title) in zip(axes[0], envs_and_titles, strict=True):
        draw_map(ax, env)
        ax.set_title(title)
    return fig, axes[0]


def save(fig, path) -> None:
    """Saves and closes a figure."""
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


# --- training curves (from metrics.jsonl rows) ----------------------------------------


def _series(rows: list[dict], key: str):
    """(env_steps (n,), values (n, n_seeds)) of the rows that hold `key`."""
    rows = [r for r in rows if key in r]
    steps = np.array([r["env_steps"] for r in rows], np.float64)
    values = np.array([np.atleast_1d(r[key]) for r in rows], np.float64)
    return steps, values.reshape(len(rows), -1)


def _mean_std_line(ax, steps, values, label, color=None) -> None:
    """Mean over seeds with a +-std band (no band for one seed)."""
    mean, std = values.mean(axis=1), values.std(axis=1)
    (line,) = ax.plot(steps, mean, label=label, color=color)
    if values.shape[1] > 1:
        ax.fill_between(steps, mean - std, mean + std, color=line.get_color(), alpha=0.2)


def training_minutes(rows: list[dict]) -> tuple[np.ndarray, np.ndarray]:
    """(env_steps (n,), minutes (n,)): wall-clock minutes of training up to each row, the
    running sum of `time/iteration_s` (so a resumed run's restarted clock and its compile
    time do not count)."""
    rows = [r for r in rows if "time/iteration_s" in r]
    steps = np.array([r["env_steps"] for r in rows], np.float64)
    minutes = np.cumsum([r["time/iteration_s"] for r in rows]) / 60.0
    return steps, minutes


def _minutes_axis(ax, rows: list[dict]) -> None:
    """A top x axis in training minutes, mapped from the env steps below it."""
    steps, minutes = training_minutes(rows)
    if len(steps) < 2:
        return
    top = ax.secondary_xaxis(
        "top",
        functions=(lambda s: np.interp(s, steps, minutes), lambda m: np.interp(m, minutes, steps)),
    )
    top.set_xlabel("minutes")


def success_curve(rows: list[dict], n_modes: int, path) -> None:
    """eval/success per mode and their mean over env steps (mean +- std over seeds), with
    the training minutes on a top axis."""
    fig, ax = plt.subplots(figsize=(6, 4))
    for k in range(n_modes):
        steps, values = _series(rows, f"eval/success/{k}")
        _mean_std_line(ax, steps, values, f"mode {k}")
    steps, values = _series(rows, "eval/success")
    _mean_std_line(ax, steps, values, "mean", color="k")
    _minutes_axis(ax, rows)
    ax.set_xlabel("env steps")
    ax.set_ylabel("success")
    ax.set_ylim(-0.05, 1.05)
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    save(fig, path)


def metric_curve(rows: list[dict], key: str, path, ylabel: str | None = None) -> None:
    """One metric over env steps (mean +- std over seeds)."""
    fig, ax = plt.subplots(figsize=(6, 4))
    steps, values = _series(rows, key)
    _mean_std_line(ax, steps, values, key)
    ax.set_xlabel("env steps")
    ax.set_ylabel(ylabel or key)
    ax.grid(alpha=0.3)
    save(fig, path)


def curriculum_snapshots(rows: list[dict], env, path, n_panels: int = 4) -> None:
    """Curriculum goals over the map at `n_panels` moments of training (paper Fig. 8).

    Uses the `curriculum/goals` of evaluation rows (the first seed's, for sweeps).
    """
    rows = [r for r in rows if "curriculum/goals" in r]
    if not rows:
        return
    picks = sorted(set(np.linspace(0, len(rows) - 1, min(n_panels, len(rows))).astype(int)))
    fig, axes = plt.subplots(1, len(picks), figsize=(4 * len(picks), 4), squeeze=False)
    for ax, i in zip(axes[0], picks, strict=True):
        goals = np.asarray(rows[i]["curriculum/goals"], np.float64)
        goals = goals.reshape(-1, goals.shape[-2], goals.shape[-1])[0]  # first seed
        draw_map(ax, env)
        draw_points(ax, goals[:, :2], color="tab:green", size=18)
        ax.set_title(f"{rows[i]['env_steps']:,} env steps")
    save(fig, path)
