"""Maze layouts (SPEC.md §8) and the geometry derived from them.

A layout is a tuple of equal-length row strings: `#` wall, `.` free, `S` the start
cell, whose centre is the origin. Rows run from +y down to -y, columns from -x to +x,
and every cell is `cell_size` wide. Everything here is host-side numpy, computed once
when an env is built.
"""

from __future__ import annotations

import collections

import mujoco
import numpy as np

CELL_SIZE = 4.0

LAYOUTS: dict[str, tuple[str, ...]] = {
    "complex_maze": (
        "###########",
        "#.#.......#",
        "#.#.#######",
        "#.#.#.....#",
        "#.#.#.###.#",
        "#.#..S..#.#",
        "#.###.#.#.#",
        "#.....#.#.#",
        "#######.#.#",
        "#.......#.#",
        "###########",
    ),
    "medium_maze": (
        "###########",
        "#.........#",
        "#.###.###.#",
        "#.###.###.#",
        "#.###.###.#",
        "#....S....#",
        "#.###.###.#",
        "#.###.###.#",
        "#.###.###.#",
        "#.........#",
        "###########",
    ),
    "spiral_maze": (
        "#########",
        "###.....#",
        "###.#####",
        "#...#...#",
        "#.###.#.#",
        "#.#.S.#.#",
        "#.#.###.#",
        "#...#...#",
        "#####.###",
        "#.....###",
        "#########",
    ),
    "ant": (
        "#####",
        "#...#",
        "#.###",
        "#.S.#",
        "###.#",
        "#...#",
        "#####",
    ),
}


def start_cell(layout: tuple[str, ...]) -> tuple[int, int]:
    """(row, col) of the `S` cell."""
    for r, row in enumerate(layout):
        if "S" in row:
            return r, row.index("S")
    raise ValueError("layout has no start cell 'S'")


def validate_layout(layout: tuple[str, ...]) -> None:
    """Raises ValueError unless rows are equal, use only '#.S', hold one S and a wall ring."""
    if not layout or len({len(row) for row in layout}) != 1:
        raise ValueError("layout rows must be non-empty and of equal length")
    if set("".join(layout)) - set("#.S"):
        raise ValueError("layout may only contain '#', '.' and 'S'")
    if sum(row.count("S") for row in layout) != 1:
        raise ValueError("layout must contain exactly one start cell 'S'")
    ring = layout[0] + layout[-1] + "".join(row[0] + row[-1] for row in layout)
    if set(ring) != {"#"}:
        raise ValueError("layout must be enclosed by a ring of walls")


def cell_center(layout: tuple[str, ...], cell: tuple[int, int], cell_size: float) -> np.ndarray:
    """World xy (2,) of the centre of cell (row, col)."""
    r0, c0 = start_cell(layout)
    r, c = cell
    return np.array([(c - c0) * cell_size, (r0 - r) * cell_size], np.float32)


def point_to_cell(layout: tuple[str, ...], xy, cell_size: float) -> tuple[int, int]:
    """(row, col) of the cell containing world point xy."""
    rows, cols = points_to_cells(layout, np.asarray(xy, np.float64)[None], cell_size)
    return int(rows[0]), int(cols[0])


def points_to_cells(
    layout: tuple[str, ...], xy: np.ndarray, cell_size: float
) -> tuple[np.ndarray, np.ndarray]:
    """Rows (n,) and cols (n,) int of the cells containing world points xy (n, 2)."""
    r0, c0 = start_cell(layout)
    cols = np.floor(xy[:, 0] / cell_size + 0.5).astype(int) + c0
    rows = r0 - np.floor(xy[:, 1] / cell_size + 0.5).astype(int)
    return rows, cols


def wall_cells(layout: tuple[str, ...]) -> list[tuple[int, int]]:
    """(row, col) of every wall cell."""
    return [(r, c) for r, row in enumerate(layout) for c, ch in enumerate(row) if ch == "#"]


def wall_centers(layout: tuple[str, ...], cell_size: float) -> np.ndarray:
    """(n_walls, 2) world xy centres of the wall cells (each a box of half-size cell_size/2)."""
    return np.stack([cell_center(layout, rc, cell_size) for rc in wall_cells(layout)])


def interior_bounds(layout: tuple[str, ...], cell_size: float) -> tuple[np.ndarray, np.ndarray]:
    """(low, high) world xy of the region inside the outer wall ring."""
    rows, cols = len(layout), len(layout[0])
    top_left = cell_center(layout, (1, 1), cell_size)
    bottom_right = cell_center(layout, (rows - 2, cols - 2), cell_size)
    half = cell_size / 2.0
    low = np.array([top_left[0] - half, bottom_right[1] - half], np.float32)
    high = np.array([bottom_right[0] + half, top_left[1] + half], np.float32)
    return low, high


def is_free(layout: tuple[str, ...], cell: tuple[int, int]) -> bool:
    """True if (row, col) is inside the layout and not a wall."""
    r, c = cell
    return 0 <= r < len(layout) and 0 <= c < len(layout[0]) and layout[r][c] != "#"


def shortest_path(
    layout: tuple[str, ...], start: tuple[int, int], goal: tuple[int, int]
) -> list[tuple[int, int]]:
    """Breadth-first shortest path of 4-connected free cells, start and goal included.

    Raises:
      ValueError: if either end is a wall or the goal is unreachable.
    """
    if not (is_free(layout, start) and is_free(layout, goal)):
        raise ValueError(f"path ends must be free cells, got {start} -> {goal}")
    parent: dict[tuple[int, int], tuple[int, int] | None] = {start: None}
    queue = collections.deque([start])
    while queue:
        cell = queue.popleft()
        if cell == goal:
            path = [cell]
            while parent[path[-1]] is not None:
                path.append(parent[path[-1]])
            return path[::-1]
        r, c = cell
        for nxt in ((r - 1, c), (r + 1, c), (r, c - 1), (r, c + 1)):
            if is_free(layout, nxt) and nxt not in parent:
                parent[nxt] = cell
                queue.append(nxt)
    raise ValueError(f"cell {goal} is unreachable from {start}")


def add_walls_to_spec(
    spec: mujoco.MjSpec,
    layout: tuple[str, ...],
    cell_size: float,
    half_height: float,
    contype: int = 0,
    conaffinity: int = 0,
) -> None:
    """Adds one box geom per wall cell to the world body of `spec`.

    Args:
      spec: the model spec to extend.
      layout: the maze layout.
      cell_size: width of a cell; each box has half-size cell_size/2 in x and y.
      half_height: box half-extent in z (the box sits on z = 0).
      contype, conaffinity: collision bits (0, 0 for walls that only a kinematic
        agent collides with, outside the physics).
    """
    half = cell_size / 2.0
    for i, (x, y) in enumerate(wall_centers(layout, cell_size)):
        spec.worldbody.add_geom(
            name=f"wall_{i}",
            type=mujoco.mjtGeom.mjGEOM_BOX,
            size=[half, half, half_height],
            pos=[float(x), float(y), half_height],
            rgba=[0.55, 0.45, 0.35, 1.0],
            contype=contype,
            conaffinity=conaffinity,
        )
