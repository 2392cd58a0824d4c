"""The map drawing helper draws every wall cell and goal point."""

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.patches import Circle, Rectangle

from d2c_jax import plots
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
