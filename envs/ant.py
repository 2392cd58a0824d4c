"""The Ant (SPEC.md §8): an 8-joint quadruped in a walled 12 x 20 arena, simulated in MJX.

The ant (envs/xmls/ant.xml, written for this project) is the classic gym/rllab quadruped
with OUTPACE's torque scale (gear 30, ctrl in [-1, 1]). The arena's walls are physical
boxes built from `LAYOUT`; the goal is the torso's xy. No termination: a fallen ant
simply keeps going until the horizon.

MJX settings, chosen for speed and checked for stability in tests/test_ant.py (env steps/s
against C MuJoCo: benchmarks/RESULTS.md, "Environments"):
- Contacts: torso and shins with the floor, torso and shins with the walls, nothing else
  (collision bits in ant.xml; no self-collision, no floor-wall pairs). Wall-box pairs
  dominate the cost of a step (each body geom is tested against every box), so the thighs
  and hip stubs, which a wall can only reach after a shin or the torso has touched it, are
  left out: 30 wall pairs instead of 54.
- Wall merging: the 22 wall cells of the layout are covered greedily by 6 boxes
  (`wall_boxes`); per-cell boxes would give 110 wall pairs instead of 30.
- Wall contacts are frictionless (the walls have condim 1 and geom priority 1, so their
  condim wins): one constraint row per contact instead of four. MJX solves only the
  `MAX_CONTACT_POINTS` deepest of the 54 potential wall contacts (a custom numeric);
  the 9 floor contacts (condim 3) are never cut.
- Integrator: RK4, the paper's (OUTPACE's ant.xml), at SPEC §8's timestep. Until
  2026-12-04 it was Euler, chosen for speed; at dt = 0.01 Euler's contact dynamics are
  too coarse for this light ant: a fast open-loop gait covers 17.2 units of path in H
  steps with a converged Euler solve against 21.7 under RK4 (Euler at half the timestep
  gives 20.7, so the loss is Euler's discretisation error, not a different physics), and
  a gait search finds a best displacement of 12.8 units under Euler against 23.3. The
  nearer mode is 20 units of corridor away (`python -m benchmarks.ant_gait --mjx`). RK4
  costs 2.8x Euler's MJX step at batch 64 and 3.6x at batch 1 on this 2-core CPU
  (`python -m benchmarks.envs --envs ant`; docs/DEVIATIONS.md, "The Ant's physics").
- Solver: Newton, 2 iterations, 4 line-search iterations, pyramidal friction cones
  (MuJoCo's default). Under RK4, 2 iterations keep the gait's path within 1% of a
  converged solve (tests/test_ant.py keeps it within 10%); one iteration lets the feet
  slip (a third of the path lost under Euler before 2026-12-02). In MJX (not C MuJoCo)
  a multi-iteration solve lets a torso thrown at 20-30 m/s pass the outer wall; ten
  times the fastest gait (15 m/s) is held (tests/test_ant.py).
"""

from __future__ import annotations

import os

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import mjx

from envs import layouts
from envs.base import GoalEnv, put_mjx, scan_substeps

XML_PATH = os.path.join(os.path.dirname(__file__), "xmls", "ant.xml")

# SPEC §8 arena (rows from +y down to -y, columns from -x to +x; S is the origin).
LAYOUT: tuple[str, ...] = layouts.LAYOUTS["ant"]
CELL_SIZE = layouts.CELL_SIZE
WALL_HALF_HEIGHT = 1.0
"""Walls are boxes standing on the floor, 2 high."""

TIMESTEP = 0.01
"""Physics timestep in seconds."""
N_SUBSTEPS = 5
"""Physics steps per env step (an env step is 0.05 s)."""
SOLVER_ITERATIONS = 2
"""Newton iterations per physics step."""
LS_ITERATIONS = 4
"""Line-search iterations per Newton iteration."""
MAX_CONTACT_POINTS = 16
"""Most wall contacts (the deepest) that enter the solver each step (MJX only)."""

START_POS = (0.0, 0.0, 0.75)
# Joint angles of the start pose (hip, ankle per leg): hips centred, ankles at the
# middle of their 30-70 degree range, with the sign of each leg.
START_JOINTS = tuple(np.deg2rad([0, 50, 0, -50, 0, -50, 0, 50]).tolist())
START_QPOS = (*START_POS, 1.0, 0.0, 0.0, 0.0, *START_JOINTS)
"""qpos (15,) of the start pose: torso position, identity quaternion, joint angles."""
RESET_QPOS_NOISE = 0.1
"""qpos noise: U[-0.1, 0.1] on every coordinate (the quaternion is renormalised)."""
RESET_QVEL_STD = 0.1
"""qvel noise: N(0, 0.1^2)."""

# normalize_obs scales (typical magnitudes under random actions; see tests/test_ant.py).
Z_CENTRE, Z_SCALE = 0.5, 0.25
LIN_VEL_SCALE = 1.0
ANG_VEL_SCALE = 2.0
JOINT_VEL_SCALE = 4.0


def wall_boxes(layout: tuple[str, ...]) -> list[tuple[int, int, int, int]]:
    """Covers the wall cells greedily by rectangles of cells.

    Row-major, each uncovered wall cell starts a rectangle that grows right over wall
    cells (covered or not), then down while the whole span is wall. Rectangles may
    overlap; their union is exactly the wall cells.

    Returns:
      (row0, col0, row1, col1) inclusive cell ranges, one per box.
    """
    wall = np.array([[ch == "#" for ch in row] for row in layout])
    covered = np.zeros_like(wall)
    boxes = []
    n_rows, n_cols = wall.shape
    for r in range(n_rows):
        for c in range(n_cols):
            if not wall[r, c] or covered[r, c]:
                continue
            c1 = c
            while c1 + 1 < n_cols and wall[r, c1 + 1]:
                c1 += 1
            r1 = r
            while r1 + 1 < n_rows and wall[r1 + 1, c : c1 + 1].all():
                r1 += 1
            covered[r : r1 + 1, c : c1 + 1] = True
            boxes.append((r, c, r1, c1))
    return boxes


def wall_box_geometry(layout: tuple[str, ...], cell_size: float) -> tuple[np.ndarray, np.ndarray]:
    """World xy centres (n, 2) and xy half-sizes (n, 2) of the merged wall boxes."""
    r_s, c_s = layouts.start_cell(layout)
    centres, halves = [], []
    for r0, c0, r1, c1 in wall_boxes(layout):
        centres.append([((c0 + c1) / 2 - c_s) * cell_size, (r_s - (r0 + r1) / 2) * cell_size])
        halves.append([(c1 - c0 + 1) * cell_size / 2, (r1 - r0 + 1) * cell_size / 2])
    return np.array(centres, np.float32), np.array(halves, np.float32)


def build_ant_model(
    layout: tuple[str, ...] = LAYOUT,
    cell_size: float = CELL_SIZE,
    iterations: int = SOLVER_ITERATIONS,
    ls_iterations: int = LS_ITERATIONS,
    max_contact_points: int = MAX_CONTACT_POINTS,
) -> mujoco.MjModel:
    """The ant of ant.xml plus the arena walls and the MJX solver settings."""
    spec = mujoco.MjSpec.from_file(XML_PATH)
    spec.option.timestep = TIMESTEP
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_RK4
    spec.option.solver = mujoco.mjtSolver.mjSOL_NEWTON
    spec.option.iterations = iterations
    spec.option.ls_iterations = ls_iterations
    centres, halves = wall_box_geometry(layout, cell_size)
    for i, ((x, y), (hx, hy)) in enumerate(zip(centres, halves, strict=True)):
        # Collision bit 1 (walls, see ant.xml); priority 1 makes the wall's condim 1 (no
        # friction) win over the body geom's condim 3.
        spec.worldbody.add_geom(
            name=f"wall_{i}",
            type=mujoco.mjtGeom.mjGEOM_BOX,
            size=[float(hx), float(hy), WALL_HALF_HEIGHT],
            pos=[float(x), float(y), WALL_HALF_HEIGHT],
            contype=0,
            conaffinity=2,
            condim=1,
            priority=1,
            rgba=[0.55, 0.45, 0.35, 1.0],
        )
    # MJX keeps only the deepest `max_contact_points` contacts per condim group: the
    # frictionless wall group (the floor group has 9 contacts and is never cut).
    spec.add_numeric(name="max_contact_points", data=[float(max_contact_points)])
    return spec.compile()


def reset_qpos_qvel(key: jax.Array) -> tuple[jax.Array, jax.Array]:
    """SPEC §8's reset: qpos (15,) = START_QPOS + U[-0.1, 0.1] (quaternion renormalised),
    qvel (14,) ~ N(0, 0.1^2)."""
    key_pos, key_vel = jax.random.split(key)
    nq = len(START_QPOS)
    qpos = jnp.asarray(START_QPOS, jnp.float32) + jax.random.uniform(
        key_pos, (nq,), minval=-RESET_QPOS_NOISE, maxval=RESET_QPOS_NOISE
    )
    qpos = qpos.at[3:7].set(qpos[3:7] / jnp.linalg.norm(qpos[3:7]))
    qvel = RESET_QVEL_STD * jax.random.normal(key_vel, (nq - 1,))  # free joint: 7 qpos, 6 dofs
    return qpos, qvel


class Ant(GoalEnv):
    """The ant in the SPEC §8 arena: obs (29) = qpos[:15] + qvel[:14], action (8), goal = torso xy.

    Attributes (beyond GoalEnv's):
      layout, cell_size: the arena (SPEC §8).
      mj_model: the mujoco.MjModel (for C MuJoCo, rendering and benchmarks).
      mjx_model: the same model on device.
    """

    obs_dim = 29
    action_dim = 8
    goal_dim = 2
    horizon = 300  # a class constant: envs.horizon(name) reads it without building the env
    success_radius = 1.0

    def __init__(
        self,
        iterations: int = SOLVER_ITERATIONS,
        ls_iterations: int = LS_ITERATIONS,
        max_contact_points: int = MAX_CONTACT_POINTS,
    ):
        """Builds the model.

        Args:
          iterations, ls_iterations: Newton solver and line-search iteration counts.
          max_contact_points: most wall contacts that enter the MJX solver.
        """
        self.name = "ant"
        self.layout = LAYOUT
        self.cell_size = CELL_SIZE
        self.goal_points = np.array([[4.0, 8.0], [-4.0, -8.0]], np.float32)
        self.goal_low = np.array([-6.0, -10.0], np.float32)
        self.goal_high = np.array([6.0, 10.0], np.float32)
        self.goal_noise_mask = np.ones(2, np.float32)
        self.wall_centres, self.wall_halves = wall_box_geometry(LAYOUT, CELL_SIZE)
        self.mj_model = build_ant_model(
            iterations=iterations,
            ls_iterations=ls_iterations,
            max_contact_points=max_contact_points,
        )
        self.mjx_model, self._data_template = put_mjx(self.mj_model)
        self.start_qpos = np.array(START_QPOS, np.float32)
        lo, hi = self.mj_model.jnt_range[1:].T  # hinge ranges (the free joint has none)
        self._joint_centre = ((lo + hi) / 2).astype(np.float32)
        self._joint_half = ((hi - lo) / 2).astype(np.float32)

    # --- GoalEnv hooks ----------------------------------------------------------
    def _reset_data(self, key: jax.Array) -> mjx.Data:
        # Only qpos/qvel are set: the first mjx.step recomputes everything else, so the
        # derived fields (xpos, contacts...) are the template's until then (run
        # mjx.forward on the state to render it).
        qpos, qvel = reset_qpos_qvel(key)
        return self._data_template.replace(qpos=qpos, qvel=qvel)

    def _step_data(self, data: mjx.Data, action: jax.Array) -> mjx.Data:
        data = data.replace(ctrl=action)
        return scan_substeps(lambda d: mjx.step(self.mjx_model, d), data, N_SUBSTEPS)

    def _observe(self, data: mjx.Data, prev_data: mjx.Data | None) -> jax.Array:
        return jnp.concatenate([data.qpos[:15], data.qvel[:14]]).astype(jnp.float32)

    def _achieved_goal(self, data: mjx.Data) -> jax.Array:
        return data.qpos[:2].astype(jnp.float32)

    def goal_of_obs(self, obs: jax.Array) -> jax.Array:
        """phi from an observation (..., 29) -> (..., 2): the torso xy, obs[:2]."""
        return obs[..., 0:2]

    def normalize_obs(self, obs: jax.Array) -> jax.Array:
        """(..., 29) -> (..., 29), each feature about [-1, 1].

        Torso xy by the goal bounds, z by (z - 0.5) / 0.25, the unit quaternion as is, the
        joint angles linearly from their ranges onto [-1, 1] (the joints are bounded, so a
        linear map is faithful and sin/cos is not needed), and velocities divided by fixed
        scales: torso linear 1 m/s, torso angular 2 rad/s, joints 4 rad/s (about the 99th
        percentile of |v| under random actions).
        """
        xy = self.normalize_goal(obs[..., 0:2])
        z = (obs[..., 2:3] - Z_CENTRE) / Z_SCALE
        quat = obs[..., 3:7]
        joints = (obs[..., 7:15] - self._joint_centre) / self._joint_half
        lin_vel = obs[..., 15:18] / LIN_VEL_SCALE
        ang_vel = obs[..., 18:21] / ANG_VEL_SCALE
        joint_vel = obs[..., 21:29] / JOINT_VEL_SCALE
        return jnp.concatenate([xy, z, quat, joints, lin_vel, ang_vel, joint_vel], axis=-1)

    @property
    def start_goal(self) -> np.ndarray:
        """(2,) the torso's noiseless start xy, the origin."""
        return np.asarray(START_POS[:2], np.float32)
