"""Host-side matplotlib drawings: maps with walls, goal points, points and trajectories,
and training curves from metrics.jsonl rows (one run, seeds, sweep arms, several runs).

The trainer uses these for curriculum pictures (paper Fig. 8); the demo for random
rollouts. Nothing here runs inside jit.
"""

from __future__ import annotations

import itertools
import pathlib
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
    if not rows:  # (0, 0): numpy cannot infer the seed axis of nothing
        return steps, np.zeros((0, 0))
    values = np.array([np.atleast_1d(r[key]) for r in rows], np.float64)
    return steps, values.reshape(len(rows), -1)


def _band_line(ax, steps, mean, std, label, band: bool, color=None, linestyle="-") -> None:
    """A mean line (n,) with a shaded +-std band (n,) in its colour when `band`."""
    (line,) = ax.plot(steps, mean, label=label, color=color, linestyle=linestyle)
    if band:
        ax.fill_between(steps, mean - std, mean + std, color=line.get_color(), alpha=0.2)


def _mean_std_line(ax, steps, values, label, color=None) -> None:
    """Mean over seeds of values (n, n_seeds) with a +-std band (no band for one seed)."""
    if not len(steps):  # a metric never logged (e.g. no evaluation yet): nothing to draw
        return
    mean, std = values.mean(axis=1), values.std(axis=1)
    _band_line(ax, steps, mean, std, label, band=values.shape[1] > 1, color=color)


def training_minutes(rows: list[dict]) -> tuple[np.ndarray, np.ndarray]:
    """(env_steps (n,), minutes (n,)): wall-clock minutes of training up to each row, the
    running sum of `time/iteration_s` (so a resumed run's restarted clock and its compile
    time do not count)."""
    rows = [r for r in rows if "time/iteration_s" in r]
    steps = np.array([r["env_steps"] for r in rows], np.float64)
    minutes = np.cumsum([r["time/iteration_s"] for r in rows]) / 60.0
    return steps, minutes


def interp_extended(x, xp: np.ndarray, fp: np.ndarray) -> np.ndarray:
    """np.interp, continued linearly past both ends with the end segments' slopes: x (...)
    -> (...). The axis margins lie outside the data, and np.interp's clamping there would
    map every tick past the last row onto the same point, stacking their labels."""
    x = np.asarray(x, np.float64)
    y = np.interp(x, xp, fp)
    low_slope = (fp[1] - fp[0]) / (xp[1] - xp[0])
    high_slope = (fp[-1] - fp[-2]) / (xp[-1] - xp[-2])
    y = np.where(x < xp[0], fp[0] + (x - xp[0]) * low_slope, y)
    return np.where(x > xp[-1], fp[-1] + (x - xp[-1]) * high_slope, y)


def _minutes_axis(ax, rows: list[dict]) -> None:
    """A top x axis in training minutes, mapped from the env steps below it."""
    steps, minutes = training_minutes(rows)
    if len(steps) < 2:
        return
    top = ax.secondary_xaxis(
        "top",
        functions=(
            lambda s: interp_extended(s, steps, minutes),
            lambda m: interp_extended(m, minutes, steps),
        ),
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


# --- sweeps and comparisons -------------------------------------------------------------


def _format_value(value) -> str:
    """A swept value for a label: floats as `:g` (0.0 -> "0", 0.005 -> "0.005")."""
    return f"{value:g}" if isinstance(value, float) else str(value)


def arm_labels(sweep) -> list[str]:
    """One label per arm of a sweep, in run order.

    Args:
      sweep: (dotted field, values) pairs, as config.json's `sweep` (lists) or
        TrainConfig.sweep (tuples); empty = no sweep.

    Returns:
      n_arms labels, e.g. "diversity_weight=0, tau=0.005": the arms are the Cartesian
      product of the value lists with the last field varying fastest (as the runs are
      laid out); ["all runs"] for an empty sweep (one arm holding every seed).
    """
    if not sweep:
        return ["all runs"]
    names = [field.rsplit(".", 1)[-1] for field, _ in sweep]
    return [
        ", ".join(f"{name}={_format_value(v)}" for name, v in zip(names, arm, strict=True))
        for arm in itertools.product(*(values for _, values in sweep))
    ]


def _arm_stats(values, n_arms: int, n_seeds: int):
    """(mean (n_arms, T), std (n_arms, T)) over seeds of values (T, n_arms * n_seeds).

    Run r = arm * n_seeds + seed, so a row-major reshape puts arms before seeds.
    """
    per_arm = values.reshape(len(values), n_arms, n_seeds)
    return per_arm.mean(axis=2).T, per_arm.std(axis=2).T


def per_arm_success(rows: list[dict], n_arms: int, n_seeds: int):
    """Eval success per sweep arm over the evaluation rows.

    Args:
      rows: metrics.jsonl rows; those with "eval/success" count (a number for one run,
        else a list of n_arms * n_seeds, run r = arm * n_seeds + seed).

    Returns:
      (env_steps (T,), mean (n_arms, T), std (n_arms, T)): mean and population std over
      each arm's seeds (std 0 for one seed).

    Raises:
      ValueError: the rows hold a different number of runs than n_arms * n_seeds.
    """
    steps, values = _series(rows, "eval/success")  # (T,), (T, runs)
    if len(steps) and values.shape[1] != n_arms * n_seeds:
        raise ValueError(
            f"eval/success has {values.shape[1]} runs per row, expected "
            f"{n_arms} arms x {n_seeds} seeds = {n_arms * n_seeds}"
        )
    return (steps, *_arm_stats(values, n_arms, n_seeds))


def _success_axes(ax, title: str) -> None:
    """Labels, limits, legend and grid of a success-over-env-steps panel."""
    ax.set_xlabel("env steps")
    ax.set_ylabel("eval success")
    ax.set_ylim(-0.05, 1.05)
    ax.set_title(title, fontsize=10)
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)


def _seeds_text(n: int) -> str:
    """A seed count in words: 1 seed, 3 seeds."""
    return f"{n} seed" if n == 1 else f"{n} seeds"


def sweep_success_curves(rows: list[dict], sweep, n_seeds: int, path) -> None:
    """Eval success of each sweep arm over env steps, mean +- std over its seeds (one
    curve per setting with a shaded std, as the D2C paper's ablation figure 10), with
    the training minutes on a top axis.

    Args:
      rows: metrics.jsonl rows (eval/success of n_arms * n_seeds runs).
      sweep: (dotted field, values) pairs (`arm_labels`); empty = one arm of n_seeds.
      n_seeds: seeds per arm.
      path: the .png to write.
    """
    labels = arm_labels(sweep)
    steps, mean, std = per_arm_success(rows, len(labels), n_seeds)
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for label, m, s in zip(labels, mean, std, strict=True):
        _band_line(ax, steps, m, s, label, band=n_seeds > 1)
    _minutes_axis(ax, rows)
    arms = "1 arm" if len(labels) == 1 else f"{len(labels)} arms"
    spread = ": mean ± std over seeds" if n_seeds > 1 else ""
    _success_axes(ax, f"eval success, {arms} × {_seeds_text(n_seeds)}{spread}")
    save(fig, path)


def compare_runs(run_dirs_and_rows, path, sweeps=None, metric: str = "eval/success") -> None:
    """One metric (eval success by default) of several run directories in one figure,
    mean +- std over all runs of each directory, or over the seeds of each arm when a
    directory is a sweep.

    Args:
      run_dirs_and_rows: (run directory, its metrics.jsonl rows) pairs; a directory's
        name labels its curves ("NAME: ARM" for a sweep's arms).
      path: the .png to write.
      sweeps: one sweep ((field, values) pairs, `arm_labels`) per directory, () for one
        without; None = no sweeps. The seeds per arm are the runs per row / the arms.
      metric: the metrics.jsonl key to draw (a number per run in a row), e.g.
        "curriculum/distance" (the paper's Figs. 4 and 9).

    Raises:
      ValueError: a directory without rows holding `metric`, or whose runs per row are
        not a whole number per arm.
    """
    run_dirs_and_rows = list(run_dirs_and_rows)
    sweeps = [()] * len(run_dirs_and_rows) if sweeps is None else list(sweeps)
    fig, ax = plt.subplots(figsize=(7, 4.5))
    # One line style per directory, so a directory's arms read as one group.
    styles = itertools.cycle(["-", "--", ":", "-."])
    for (run_dir, rows), sweep in zip(run_dirs_and_rows, sweeps, strict=True):
        style = next(styles)
        name = pathlib.Path(run_dir).resolve().name or str(run_dir)
        steps, values = _series(rows, metric)  # (T,), (T, runs)
        labels = arm_labels(sweep)
        if not len(steps):
            what = "evaluation rows (eval/success)" if metric == "eval/success" else metric
            raise ValueError(f"{run_dir}: no {what} in its metrics")
        if values.shape[1] % len(labels):
            raise ValueError(
                f"{run_dir}: {values.shape[1]} runs per row do not split into {len(labels)} arms"
            )
        n_seeds = values.shape[1] // len(labels)
        mean, std = _arm_stats(values, len(labels), n_seeds)
        for label, m, s in zip(labels, mean, std, strict=True):
            text = f"{name} ({_seeds_text(n_seeds)})" if not sweep else f"{name}: {label}"
            _band_line(ax, steps, m, s, text, band=n_seeds > 1, linestyle=style)
    if metric == "eval/success":
        _success_axes(ax, "eval success, mean ± std over seeds")
    else:
        ax.set(xlabel="env steps", ylabel=metric)
        ax.set_title(f"{metric}, mean ± std over seeds", fontsize=10)
        ax.legend(fontsize=8)
        ax.grid(alpha=0.3)
    save(fig, path)
