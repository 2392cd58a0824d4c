"""The map drawing helper draws every wall cell and goal point; training curves, sweep
arms and run comparisons from synthetic metrics.jsonl rows."""

import json
import os
import subprocess
import sys

import matplotlib.pyplot as plt
import numpy as np
import pytest
from matplotlib.patches import Circle, Rectangle

from d2c_jax import config as config_lib
from d2c_jax.training import commands, runs
from d2c_jax.viewing import plots
from envs import layouts

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
SWEEP = [["classifier.diversity_weight", [0.0, 1.0]], ["sac.tau", [0.005, 0.01]]]


def test_draw_map_draws_walls_goals_and_trajectories(medium_maze, tmp_path):
    fig, ax = plt.subplots()
    plots.draw_map(ax, medium_maze)
    plots.draw_trajectories(ax, np.zeros((3, 5, 2)))
    plots.draw_points(ax, np.ones((4, 2)))
    rects = [p for p in ax.patches if isinstance(p, Rectangle)]
    circles = [p for p in ax.patches if isinstance(p, Circle)]
    assert len(rects) == len(layouts.wall_cells(medium_maze.layout))
    assert len(circles) == medium_maze.n_modes
    assert len(ax.lines) >= 3 * 2 + medium_maze.n_modes
    plots.save(fig, tmp_path / "map.png")
    assert (tmp_path / "map.png").stat().st_size > 1000


def test_training_minutes_sum_iteration_times_by_hand(tmp_path):
    """Minutes are the running sum of iteration times (a resumed run's clock restarts)."""
    rows = [
        {"env_steps": 100, "time/iteration_s": 30.0, "time/elapsed_s": 30.0},
        {"env_steps": 200, "time/iteration_s": 90.0, "time/elapsed_s": 120.0},
        {"env_steps": 300, "time/iteration_s": 60.0, "time/elapsed_s": 60.0},  # resumed
    ]
    steps, minutes = plots.training_minutes(rows)
    np.testing.assert_array_equal(steps, [100, 200, 300])
    np.testing.assert_allclose(minutes, [0.5, 2.0, 3.0])
    evals = [{**r, "eval/success": 0.5, "eval/success/0": 0.5} for r in rows]
    plots.success_curve(evals, 1, tmp_path / "success.png")
    assert (tmp_path / "success.png").stat().st_size > 1000


def test_minutes_axis_mapping_continues_past_the_data_by_hand():
    """Inside the rows it is np.interp; past them it follows the end segments' slopes
    (steps 100 -> 0.5 min, 200 -> 2.0, 300 -> 3.0), so ticks in the axis margins keep
    distinct positions, and the two directions invert each other."""
    steps, minutes = np.array([100.0, 200.0, 300.0]), np.array([0.5, 2.0, 3.0])
    x = np.array([0.0, 150.0, 400.0])
    mapped = plots.interp_extended(x, steps, minutes)
    np.testing.assert_allclose(mapped, [0.5 - 100 * 0.015, 1.25, 3.0 + 100 * 0.01])
    np.testing.assert_allclose(plots.interp_extended(mapped, minutes, steps), x)


def test_draw_map_draws_the_sawyer_wall_where_the_model_has_it():
    """The table map shows the central wall box at the MuJoCo model's geom (xy)."""
    import envs

    env = envs.make("sawyer_push")
    fig, ax = plt.subplots()
    plots.draw_map(ax, env, show_goals=False)
    filled = [p for p in ax.patches if isinstance(p, Rectangle) and p.get_fill()]
    assert len(filled) == 1
    wall = env.mj_model.geom(
        [i for i in range(env.mj_model.ngeom) if "wall" in env.mj_model.geom(i).name][0]
    )
    x, y = filled[0].get_xy()
    np.testing.assert_allclose(
        [x + filled[0].get_width() / 2, y + filled[0].get_height() / 2], wall.pos[:2], atol=1e-6
    )
    np.testing.assert_allclose([filled[0].get_width() / 2], [wall.size[0]], atol=1e-6)
    plt.close(fig)


# --- sweeps and comparisons -------------------------------------------------------------

# 2 arms x 2 seeds (run r = arm * 2 + seed), 3 evaluation rows between training rows.
SUCCESS = [[0.0, 0.2, 0.5, 0.5], [0.4, 0.6, 1.0, 0.0], [1.0, 1.0, 0.25, 0.75]]


def _sweep_rows(success=SUCCESS):
    """Rows as train.py writes them: every iteration, evaluation keys on some only."""
    rows = []
    for i, values in enumerate(success):
        rows.append({"iteration": 2 * i, "env_steps": 100 * (2 * i + 1), "time/iteration_s": 6.0})
        rows.append(
            {"iteration": 2 * i + 1, "env_steps": 100 * (2 * i + 2), "time/iteration_s": 6.0,
             "eval/success": values}
        )  # fmt: skip
    return rows


def _write_run(run_dir, rows, sweep=(), num_seeds=1):
    """A run directory: config.json (today's full config, so no upgrade) and metrics."""
    run_dir.mkdir(parents=True)
    values = json.loads(runs.config_to_json(config_lib.TrainConfig()))
    values.update(num_seeds=num_seeds, seed=3, sweep=[list(pair) for pair in sweep])
    (run_dir / "config.json").write_text(json.dumps(values))
    (run_dir / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    return run_dir


def _is_png(path) -> bool:
    return path.read_bytes()[:8] == PNG_MAGIC


def test_arm_labels_follow_the_product_with_the_last_field_fastest():
    assert plots.arm_labels(SWEEP) == [
        "diversity_weight=0, tau=0.005",
        "diversity_weight=0, tau=0.01",
        "diversity_weight=1, tau=0.005",
        "diversity_weight=1, tau=0.01",
    ]
    # TrainConfig.sweep holds tuples; strings are kept as they are.
    assert plots.arm_labels((("env", ("a", "b")),)) == ["env=a", "env=b"]
    assert plots.arm_labels(()) == plots.arm_labels([]) == ["all runs"]


def test_per_arm_success_by_hand():
    steps, mean, std = plots.per_arm_success(_sweep_rows(), n_arms=2, n_seeds=2)
    np.testing.assert_array_equal(steps, [200, 400, 600])
    # arm 0 = runs 0, 1; arm 1 = runs 2, 3.
    np.testing.assert_allclose(mean, [[0.1, 0.5, 1.0], [0.5, 0.5, 0.5]])
    np.testing.assert_allclose(std, [[0.1, 0.1, 0.0], [0.0, 0.5, 0.25]])


def test_per_arm_success_of_one_run_and_of_the_wrong_number_of_runs():
    rows = _sweep_rows([0.25, 0.5])  # one run: plain numbers
    steps, mean, std = plots.per_arm_success(rows, n_arms=1, n_seeds=1)
    np.testing.assert_array_equal(steps, [200, 400])
    np.testing.assert_allclose(mean, [[0.25, 0.5]])
    np.testing.assert_allclose(std, [[0.0, 0.0]])
    with pytest.raises(ValueError, match="4 runs per row, expected 3 arms x 2 seeds"):
        plots.per_arm_success(_sweep_rows(), n_arms=3, n_seeds=2)


def test_sweep_success_curves_write_a_png(tmp_path):
    path = tmp_path / "sweep.png"
    plots.sweep_success_curves(_sweep_rows(), SWEEP[:1], 2, path)
    assert _is_png(path)


def test_write_plots_adds_the_sweep_plot_for_several_runs(medium_maze, tmp_path):
    run_dir = _write_run(tmp_path / "run", _sweep_rows(), sweep=SWEEP[:1], num_seeds=2)
    (run_dir / "plots").mkdir()
    runs.write_plots(run_dir, medium_maze)
    assert _is_png(run_dir / "plots" / "success.png")
    assert _is_png(run_dir / "plots" / "sweep_success.png")


def test_compare_draws_runs_and_sweep_arms_into_one_png(tmp_path, monkeypatch, capsys):
    sweep_dir = _write_run(tmp_path / "sweep", _sweep_rows(), sweep=SWEEP[1:], num_seeds=2)
    single_dir = _write_run(tmp_path / "single", _sweep_rows([0.25, 0.5, 1.0]))
    out = tmp_path / "both.png"
    assert commands.plots_main(["compare", str(sweep_dir), str(single_dir), "--out", str(out)]) == 0
    assert _is_png(out)
    monkeypatch.chdir(tmp_path)  # the default --out: ./compare.png
    assert commands.plots_main(["compare", str(single_dir)]) == 0
    assert _is_png(tmp_path / "compare.png")
    assert commands.plots_main(["compare"]) == 2
    assert capsys.readouterr().err.startswith("error: compare: no run directories")


def test_compare_draws_another_metric_as_the_mean_over_seeds(tmp_path, monkeypatch, capsys):
    """`--metric curriculum/distance`: the line is the per-row mean over the 2 seeds (hand-
    computed), on the metric's own axis; a metric the runs never logged exits 2."""
    rows = [
        {"iteration": 1, "env_steps": 100, "curriculum/distance": [4.0, 2.0]},
        {"iteration": 2, "env_steps": 200, "eval/success": [0, 0]},
    ]
    rows[1]["curriculum/distance"] = [3.0, 1.0]
    run_dir = _write_run(tmp_path / "two_seeds", rows, num_seeds=2)
    figures = []
    monkeypatch.setattr(plots, "save", lambda fig, path: figures.append(fig))
    plots.compare_runs([(run_dir, rows)], tmp_path / "unused.png", metric="curriculum/distance")
    (ax,) = figures[0].axes
    (line,) = ax.get_lines()
    np.testing.assert_array_equal(line.get_xdata(), [100, 200])
    np.testing.assert_allclose(line.get_ydata(), [3.0, 2.0])
    assert ax.get_ylabel() == "curriculum/distance"
    plt.close(figures[0])
    argv = ["compare", str(run_dir), "--metric", "sac/q_mean", "--out", str(tmp_path / "q.png")]
    assert commands.plots_main(argv) == 2
    assert capsys.readouterr().err.strip().endswith("no sac/q_mean in its metrics")


def test_compare_of_a_non_run_directory_exits_2_with_one_line(tmp_path):
    env = {**os.environ, "JAX_PLATFORMS": "cpu"}
    proc = subprocess.run(
        [sys.executable, "-m", "d2c_jax.plots", "compare", str(tmp_path)],
        capture_output=True, text=True, env=env, timeout=120,
    )  # fmt: skip
    assert proc.returncode == 2
    assert proc.stderr.startswith("error: ") and proc.stderr.count("\n") == 1, proc.stderr
    assert "not a run directory" in proc.stderr
