"""The three point mazes (SPEC.md §8): a kinematic point agent in an MJX maze model.

The agent has pose (x, y, theta). An action a in [-1, 1]^2 first turns it by a_1
radians, then moves it a_0 units along the new heading (OUTPACE's action model). One
collision rule: the centre keeps a clearance of 0.4 from every wall box, measured as
the Euclidean distance to the box, so the forbidden region around a box is a rounded
rectangle. A move that would enter it stops exactly where it would first enter
(computed in closed form by ray casting, below). No contact physics acts on the agent:
its pose is written into `mjx.Data.qpos` (x, y slide joints and a z hinge) and the
velocities into `qvel`, which is all a training step needs; `mjx.forward` is left to
whoever needs the rest of Data (rendering).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import mjx

from envs import layouts
from envs.base import GoalEnv, put_mjx

CLEARANCE = 0.4
"""Distance the agent's centre keeps from every wall box."""
DT = 0.02
"""Seconds per env step; velocities are the last step's change divided by DT."""
MAX_SPEED = 1.0 / DT
"""Largest |velocity| in obs (1 unit or 1 rad per step)."""
RESET_NOISE = 0.1
"""Reset pose is (0, 0, 0) + U[-RESET_NOISE, RESET_NOISE]^3."""

# Per maze: goal points (cell centres, SPEC §8 Table 3).
GOAL_POINTS: dict[str, tuple[tuple[float, float], ...]] = {
    "complex_maze": ((8, 16), (-8, -16), (16, -8), (-16, 8)),
    "medium_maze": ((16, 16), (-16, -16), (16, -16), (-16, 16)),
    "spiral_maze": ((12, 16), (-12, -16)),
}


def wrap_angle(theta: jax.Array) -> jax.Array:
    """Wraps angles to [-pi, pi)."""
    return (theta + jnp.pi) % (2 * jnp.pi) - jnp.pi


def _slab_entry(p, v, lo, hi):
    """Entry/exit parameters of the ray p + t v through axis-aligned boxes.

    Args:
      p: (2,) ray origin; v: (2,) ray direction (may have zero components).
      lo, hi: (n, 2) box corners.
    Returns:
      t_in, t_out: (n,) parameters where the ray enters and leaves each box (t_in > t_out
        when it misses).
    """
    safe_v = jnp.where(jnp.abs(v) > 1e-12, v, 1.0)
    t1, t2 = (lo - p) / safe_v, (hi - p) / safe_v
    inside_slab = (p >= lo) & (p <= hi)
    parallel = jnp.abs(v) <= 1e-12
    t_lo = jnp.where(parallel, jnp.where(inside_slab, -jnp.inf, jnp.inf), jnp.minimum(t1, t2))
    t_hi = jnp.where(parallel, jnp.where(inside_slab, jnp.inf, -jnp.inf), jnp.maximum(t1, t2))
    return jnp.max(t_lo, axis=-1), jnp.min(t_hi, axis=-1)


def _rect_hit_time(p, v, centers, half):
    """Earliest t in [0, 1] at which the segment p + t v blocks on rectangles, else 1.

    A start point already inside a rectangle (only ever by float rounding, since moves
    stop on the boundary) blocks at t = 0 when moving inward through its nearest face
    and is ignored when moving outward, so rounding can never trap or tunnel the agent.

    Args:
      p, v: (2,) segment start and displacement.
      centers: (n, 2) rectangle centres; half: (2,) half-extents.
    """
    t_in, t_out = _slab_entry(p, v, centers - half, centers + half)
    hits = (t_in < t_out) & (t_out > 0.0) & (t_in <= 1.0)
    started_inside = t_in <= 0.0
    depth = half - jnp.abs(p - centers)  # (n, 2) penetration per axis
    axis = jnp.argmin(depth, axis=-1)  # the nearest face's axis
    outward = jnp.sign(p - centers)[jnp.arange(centers.shape[0]), axis]
    moving_in = v[axis] * outward < 0.0
    t = jnp.where(started_inside, jnp.where(moving_in, 0.0, 1.0), t_in)
    return jnp.min(jnp.where(hits, jnp.clip(t, 0.0, 1.0), 1.0))


def _circle_hit_time(p, v, centers, radius):
    """Earliest t in [0, 1] at which the segment p + t v blocks on discs, else 1.

    Solves |p + t v - c|^2 = r^2; the same inside/outward rule as `_rect_hit_time`.
    """
    d = p - centers  # (n, 2)
    a = jnp.maximum(v @ v, 1e-24)
    b = 2.0 * d @ v
    c = jnp.sum(d * d, axis=-1) - radius**2
    disc = b * b - 4.0 * a * c
    t_enter = (-b - jnp.sqrt(jnp.maximum(disc, 0.0))) / (2.0 * a)
    outside_hit = (c > 0.0) & (disc > 0.0) & (t_enter >= 0.0) & (t_enter <= 1.0)
    inside_block = (c <= 0.0) & (b < 0.0)
    t = jnp.where(inside_block, 0.0, jnp.where(outside_hit, t_enter, 1.0))
    return jnp.min(t)


def blocked_move(p: jax.Array, v: jax.Array, wall_centers: jax.Array, wall_half: float):
    """Moves p by v, stopping where the clearance to a wall box would first break.

    The forbidden region around a box (half-size h) is the set of points within
    CLEARANCE of it: the union of two rectangles (h + r, h) and (h, h + r) and four
    discs of radius r at the corners. Its first entry along the segment is the minimum
    of the entry times of these convex pieces.

    Args:
      p: (2,) start point; v: (2,) intended displacement.
      wall_centers: (n_walls, 2) box centres; wall_half: box half-size.
    Returns:
      (2,) the end point.
    """
    r = CLEARANCE
    t_x = _rect_hit_time(p, v, wall_centers, jnp.array([wall_half + r, wall_half]))
    t_y = _rect_hit_time(p, v, wall_centers, jnp.array([wall_half, wall_half + r]))
    corners = jnp.array([[1, 1], [1, -1], [-1, 1], [-1, -1]], jnp.float32) * wall_half
    all_corners = (wall_centers[:, None, :] + corners[None]).reshape(-1, 2)
    t_c = _circle_hit_time(p, v, all_corners, r)
    return p + jnp.minimum(jnp.minimum(t_x, t_y), t_c) * v


def distance_to_walls(xy: jax.Array, wall_centers: jax.Array, wall_half: float) -> jax.Array:
    """Euclidean distance from points (..., 2) to the nearest wall box: (...,)."""
    gap = jnp.maximum(jnp.abs(xy[..., None, :] - wall_centers) - wall_half, 0.0)
    return jnp.min(jnp.linalg.norm(gap, axis=-1), axis=-1)


def build_maze_model(layout: tuple[str, ...], cell_size: float) -> mujoco.MjModel:
    """The maze as a MuJoCo model: floor, one box per wall cell, the agent on x/y/yaw joints."""
    spec = mujoco.MjSpec()
    spec.option.timestep = DT
    spec.worldbody.add_geom(
        type=mujoco.mjtGeom.mjGEOM_PLANE, size=[0, 0, 0.1], rgba=[0.9, 0.9, 0.9, 1]
    )
    layouts.add_walls_to_spec(spec, layout, cell_size, half_height=0.5)
    agent = spec.worldbody.add_body(name="agent", pos=[0, 0, CLEARANCE])
    for name, jtype, axis in (
        ("x", mujoco.mjtJoint.mjJNT_SLIDE, [1, 0, 0]),
        ("y", mujoco.mjtJoint.mjJNT_SLIDE, [0, 1, 0]),
        ("yaw", mujoco.mjtJoint.mjJNT_HINGE, [0, 0, 1]),
    ):
        agent.add_joint(name=name, type=jtype, axis=axis)
    # Collision bits 0: no contact physics acts on the kinematic agent.
    agent.add_geom(
        type=mujoco.mjtGeom.mjGEOM_SPHERE,
        size=[CLEARANCE, 0, 0],
        rgba=[0.2, 0.4, 0.9, 1],
        contype=0,
        conaffinity=0,
    )
    agent.add_geom(
        type=mujoco.mjtGeom.mjGEOM_BOX,
        size=[0.3, 0.05, 0.05],
        pos=[0.3, 0, 0],
        rgba=[0.9, 0.2, 0.2, 1],
        contype=0,
        conaffinity=0,
    )
    return spec.compile()


class PointMaze(GoalEnv):
    """A kinematic point agent in one of the SPEC §8 mazes (or a custom layout).

    obs (6) = [x, y, theta, x_dot, y_dot, theta_dot]; action (2) = [move, turn];
    goal = achieved goal = agent xy.
    """

    obs_dim = 6
    action_dim = 2
    goal_dim = 2
    horizon = 100  # a class constant: envs.horizon(name) reads it without building the env
    success_radius = 0.5

    def __init__(
        self,
        maze: str = "medium_maze",
        layout: tuple[str, ...] | None = None,
        goal_points=None,
        cell_size: float = layouts.CELL_SIZE,
    ):
        """Builds the maze.

        Args:
          maze: a name in `GOAL_POINTS` (its layout and goal points), or any label when
            `layout` is given.
          layout: a custom layout (rows of '#', '.', 'S'); goal bounds are its interior.
          goal_points: (n_modes, 2) custom goal points; default: the maze's.
          cell_size: width of a layout cell.
        """
        if layout is None:
            if maze not in GOAL_POINTS:
                raise ValueError(f"unknown maze {maze!r}; known: {', '.join(GOAL_POINTS)}")
            layout = layouts.LAYOUTS[maze]
        layout = tuple(layout)
        layouts.validate_layout(layout)
        if goal_points is None:
            if maze not in GOAL_POINTS:
                raise ValueError("a custom layout needs goal_points")
            goal_points = GOAL_POINTS[maze]
        self.name = maze
        self.layout = layout
        self.cell_size = float(cell_size)
        self.goal_points = np.asarray(goal_points, np.float32).reshape(-1, 2)
        self.goal_low, self.goal_high = layouts.interior_bounds(layout, self.cell_size)
        self.goal_noise_mask = np.ones(2, np.float32)
        self.wall_centers = layouts.wall_centers(layout, self.cell_size)
        self.wall_half = self.cell_size / 2.0
        self.mj_model = build_maze_model(layout, self.cell_size)
        self.mjx_model, self._data_template = put_mjx(self.mj_model)

    # --- GoalEnv hooks ----------------------------------------------------------
    def _reset_data(self, key: jax.Array) -> mjx.Data:
        pose = jax.random.uniform(key, (3,), minval=-RESET_NOISE, maxval=RESET_NOISE)
        return self._data_template.replace(qpos=pose, qvel=jnp.zeros(3))

    def _step_data(self, data: mjx.Data, action: jax.Array) -> mjx.Data:
        xy, theta = data.qpos[:2], data.qpos[2]
        theta = wrap_angle(theta + action[1])
        move = action[0] * jnp.stack([jnp.cos(theta), jnp.sin(theta)])
        new_xy = blocked_move(xy, move, jnp.asarray(self.wall_centers), self.wall_half)
        qpos = jnp.concatenate([new_xy, theta[None]])
        delta = jnp.concatenate([new_xy - xy, wrap_angle(theta - data.qpos[2])[None]])
        return data.replace(qpos=qpos, qvel=delta / DT, time=data.time + DT)

    def _observe(self, data: mjx.Data, prev_data: mjx.Data | None) -> jax.Array:
        return jnp.concatenate([data.qpos, data.qvel]).astype(jnp.float32)

    def _achieved_goal(self, data: mjx.Data) -> jax.Array:
        return data.qpos[:2].astype(jnp.float32)

    def goal_of_obs(self, obs: jax.Array) -> jax.Array:
        """phi from an observation (..., 6) -> (..., 2): the xy position, obs[:2]."""
        return obs[..., :2]

    def normalize_obs(self, obs: jax.Array) -> jax.Array:
        """(..., 6) -> (..., 7): xy by the goal bounds, heading as (sin, cos), speeds / 50."""
        xy = self.normalize_goal(obs[..., :2])
        theta = obs[..., 2:3]
        return jnp.concatenate([xy, jnp.sin(theta), jnp.cos(theta), obs[..., 3:] / MAX_SPEED], -1)

    @property
    def start_goal(self) -> np.ndarray:
        """(2,) the start cell's centre, the origin."""
        return np.zeros(2, np.float32)
