"""The map drawing helper draws every wall cell and goal point."""

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.patches import Circle, Rectangle

from d2c_jax.viewing import plots
from envs import layouts


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
