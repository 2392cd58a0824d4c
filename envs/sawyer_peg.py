"""Sawyer peg push and pick & place (SPEC.md §8) in MJX.

A documented simplification (decided in SPEC §8): a mocap-driven two-finger gripper
stands for the Sawyer arm. The scene is our own MJCF, `xmls/sawyer_peg.xml`; only the
central wall differs between the tasks (`CENTRAL_WALL`, applied with MjSpec).

**Gripper.** The hand is a light body (0.14 kg with the fingers, gravity compensated) on
three slide joints; a `connect` equality ties its origin, the hand point between the
fingertips, to the mocap body `target`. Each env step moves the target by 0.01·a[:3] m,
clipped to the hand bounds, in 5 equal increments (one per substep). In free motion the
hand follows critically damped with time constant 0.01 s, so it moves 0.01·a per step and
trails the target by ~0.014 m at full speed. A kinematic (mocap) hand would push through a
blocked peg with unbounded force; this one is stopped by contacts, and its force is
bounded by (1) the equality's impedance d = 0.2 (solimp): static stiffness m/((1-d)·tc²) ≈
1750 N/m instead of ≈ 28,000 N/m at MuJoCo's default d = 0.95, and (2) a leash that keeps
the target within `LEASH` = 0.03 m of the hand per axis, so a blocked hand pushes with at
most ~50 N (a held peg sags ~1 mm). The fingers slide along y under position actuators (kp
250, force cap 10 N, joint damping 10) within travel limits q ∈ [0, 0.04] as stiff as the
contacts (without them a peg yawing between open pads wedged the fingers up to 27 mm past
fully open, and a learned policy exploited it; docs/DEVIATIONS.md): the target of each
finger is 0.02·(1 - grip), so grip = -1 opens fully (opening 0.08), grip = 0 just touches
a centred peg (opening 0.04 = its width) and grip > 0 squeezes it (5 N per finger at grip
= 1; pad friction 1.5 holds 15 N against the peg's 1.9 N weight). The fingertip pads are
boxes 0.04 wide (x) and 0.04 tall (z, from 0.01 below the hand point): flat faces grasp
without letting the peg swing, push the peg's long side without letting it yaw off, and
cover its whole height when low, so a push into a wall cannot pitch the peg up and wedge a
pad under it.

**Contacts.** Only explicit pairs collide (every geom has contype = conaffinity = 0):
peg-table (box-plane, condim 3, μ 0.6), peg-central wall (box-box, condim 3, μ 0.3),
peg-retaining walls (0.06-high boxes along the table's edges: box-box, condim 1,
frictionless), pads-peg (box-box, condim 3, μ 1.5): 32 contacts, 80 constraint rows, plus
3 for the equality and 2 for the finger limits. The retaining walls were half-space
planes (box-plane, about 10% cheaper per env step) until 2026-12-05; a plane is a wall of
unbounded height, and a learned pick & place policy lifted the peg by pressing it onto the
back one with a pad and climbing (docs/DEVIATIONS.md). A peg tipped over a 0.06 wall now
falls off the table, as it would off a real one. The
hand and fingers collide with nothing else (they pass through walls; the hand bounds keep
them over the table). Every pair has solref (0.005, 1), 2 substeps, the stiffest MuJoCo
advises: a peg pinched or pressed into the table or a wall sinks a few millimetres at
most.

**Solver.** Newton, 8 iterations (converged: on the recorded launch states 10 and 16
give the same peg speeds), 8 line-search iterations, pyramidal cones, Euler (implicit
joint damping); timestep 0.0025 s, 5 substeps per env step (metaworld's). With 1-2
iterations pinching the peg under random actions gives NaN; with 4, a pad pressing a
yawed peg into the central wall got an unconverged contact force that launched it at
11-16 m/s (a learned push policy: 3 pegs above 2 m/s and 1 NaN in 500 episodes) and the
runs went NaN (docs/DEVIATIONS.md).

Data fields other than qpos, qvel, mocap_pos, ctrl and time are stale right after reset
(no `mjx.forward` there); obs and φ read qpos only.
"""

from __future__ import annotations

import importlib.resources

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import mjx

from envs.base import GoalEnv, put_mjx, scan_substeps

N_SUBSTEPS = 5
"""Physics substeps (timestep 0.0025 s) per env step."""
MOVE_SCALE = 0.01
"""Metres the hand point moves per env step at |a| = 1."""
LEASH = 0.03
"""Largest per-axis distance of the mocap target from the hand point (bounds its force)."""
HAND_LOW = np.array([-0.5, 0.25, 0.01], np.float32)
HAND_HIGH = np.array([0.5, 0.95, 0.5], np.float32)
HAND_START = np.array([0.4, 0.8, 0.2], np.float32)
PEG_START = np.array([0.4, 0.8, 0.02], np.float32)
PEG_NOISE = 0.02
"""Peg start xy noise: U[-PEG_NOISE, PEG_NOISE]^2."""
FINGER_OPEN = 0.04
"""Joint position of a fully open finger; the opening (q_l + q_r) lies in [0, 0.08]."""
GOAL_XY = ((-0.3, 0.4), (-0.3, 0.8), (0.4, 0.4))
GOAL_Z = {"push": 0.02, "pick_place": 0.2}
GOAL_LOW = np.array([-0.6, 0.2, 0.0], np.float32)
GOAL_HIGH = np.array([0.6, 1.0, 0.3], np.float32)
TABLE_Z = 0.02
"""z of the peg centre resting on the table (push goals live there)."""
# Central wall (centre, half-sizes) per task: push leaves gaps at both ends; pick & place
# spans the whole table depth y in [0.2, 1.0].
CENTRAL_WALL = {
    "push": ((0.0, 0.6, 0.05), (0.01, 0.25, 0.05)),
    "pick_place": ((0.0, 0.6, 0.05), (0.01, 0.4, 0.05)),
}
XML_PATH = importlib.resources.files("envs") / "xmls" / "sawyer_peg.xml"


def build_model(task: str) -> mujoco.MjModel:
    """The scene of `task` ('push' or 'pick_place') as a MuJoCo model."""
    spec = mujoco.MjSpec.from_file(str(XML_PATH))
    pos, size = CENTRAL_WALL[task]
    wall = spec.geom("central_wall")
    wall.pos, wall.size = list(pos), list(size)
    return spec.compile()


class SawyerPeg(GoalEnv):
    """Peg push or pick & place with a mocap two-finger gripper (SPEC §8).

    obs (7) = [hand xyz, finger opening, peg xyz]; action (4) = [dx, dy, dz, grip];
    goal = achieved goal = peg centre xyz.
    """

    obs_dim = 7
    action_dim = 4
    goal_dim = 3
    horizon = 200  # a class constant: envs.horizon(name) reads it without building the env
    success_radius = 0.05

    def __init__(self, task: str = "push"):
        """Builds the task's model.

        Args:
          task: 'push' (central wall with gaps; goals on the table) or 'pick_place'
            (wall across the table; goals 0.2 m up).
        """
        if task not in CENTRAL_WALL:
            raise ValueError(f"unknown task {task!r}; known: {', '.join(CENTRAL_WALL)}")
        self.task = task
        self.name = f"sawyer_{task}"
        self.goal_points = np.array([(x, y, GOAL_Z[task]) for x, y in GOAL_XY], np.float32)
        self.goal_low, self.goal_high = GOAL_LOW.copy(), GOAL_HIGH.copy()
        centre, half = CENTRAL_WALL[task]
        # (n, 2) centres and half-sizes in xy of the obstacles a top-down map draws.
        self.obstacles_xy = (np.array([centre[:2]], np.float32), np.array([half[:2]], np.float32))
        # Push goals stay on the table: no noise on z (SPEC §1, §3, §5, §6).
        self.goal_noise_mask = np.array([1, 1, 0 if task == "push" else 1], np.float32)
        self.mj_model = build_model(task)
        self.mjx_model, data = put_mjx(self.mj_model)

        m = self.mj_model
        adr = lambda name: int(m.jnt_qposadr[m.joint(name).id])  # noqa: E731
        self._hand_adr = adr("hand_x")
        assert adr("hand_y") == self._hand_adr + 1 and adr("hand_z") == self._hand_adr + 2
        self._finger_adr = np.array([adr("finger_l"), adr("finger_r")])
        self._peg_adr = adr("peg")
        key = m.key("home")
        self._data_template = data.replace(
            qpos=jnp.asarray(key.qpos, jnp.float32),
            mocap_pos=jnp.asarray(key.mpos.reshape(-1, 3), jnp.float32),
            ctrl=jnp.asarray(key.ctrl, jnp.float32),
        )

    # --- GoalEnv hooks ----------------------------------------------------------
    def _reset_data(self, key: jax.Array) -> mjx.Data:
        noise = jax.random.uniform(key, (2,), minval=-PEG_NOISE, maxval=PEG_NOISE)
        qpos = self._data_template.qpos
        qpos = qpos.at[self._peg_adr : self._peg_adr + 2].add(noise)
        return self._data_template.replace(qpos=qpos)

    def _step_data(self, data: mjx.Data, action: jax.Array) -> mjx.Data:
        hand = self.hand_point(data)
        low, high = jnp.asarray(HAND_LOW), jnp.asarray(HAND_HIGH)
        target = jnp.clip(data.mocap_pos[0] + MOVE_SCALE * action[:3], low, high)
        # The leash: a blocked hand cannot run away from its target (bounded force).
        target = jnp.clip(jnp.clip(target, hand - LEASH, hand + LEASH), low, high)
        increment = (target - data.mocap_pos[0]) / N_SUBSTEPS
        ctrl = jnp.full((2,), 0.5 * FINGER_OPEN) * (1.0 - action[3])

        def substep(d: mjx.Data) -> mjx.Data:
            # The target moves in equal increments: no jump the hand would have to absorb.
            return mjx.step(self.mjx_model, d.replace(mocap_pos=d.mocap_pos + increment))

        return scan_substeps(substep, data.replace(ctrl=ctrl), N_SUBSTEPS)

    def _observe(self, data: mjx.Data, prev_data: mjx.Data | None) -> jax.Array:
        return jnp.concatenate(
            [self.hand_point(data), self.finger_opening(data)[None], self._achieved_goal(data)]
        ).astype(jnp.float32)

    def _achieved_goal(self, data: mjx.Data) -> jax.Array:
        return data.qpos[self._peg_adr : self._peg_adr + 3].astype(jnp.float32)

    def goal_of_obs(self, obs: jax.Array) -> jax.Array:
        """phi from an observation (..., 7) -> (..., 3): the peg centre, obs[4:7]."""
        return obs[..., 4:7]

    def normalize_obs(self, obs: jax.Array) -> jax.Array:
        """(..., 7) -> (..., 7): hand by its bounds, opening by [0, 0.08], peg by goal bounds."""
        hand_c, hand_h = (HAND_HIGH + HAND_LOW) / 2, (HAND_HIGH - HAND_LOW) / 2
        hand = (obs[..., :3] - hand_c) / hand_h
        opening = (obs[..., 3:4] - FINGER_OPEN) / FINGER_OPEN
        return jnp.concatenate([hand, opening, self.normalize_goal(obs[..., 4:])], axis=-1)

    def clip_goal(self, goal: jax.Array) -> jax.Array:
        """Clips goals (..., 3) to the bounds; push pins z to the table (0.02)."""
        goal = jnp.clip(goal, self.goal_low, self.goal_high)
        if self.task == "push":
            goal = goal.at[..., 2].set(TABLE_Z)
        return goal

    @property
    def start_goal(self) -> np.ndarray:
        """(3,) the peg's noiseless start centre."""
        return PEG_START.copy()

    # --- helpers ----------------------------------------------------------------
    def hand_point(self, data: mjx.Data) -> jax.Array:
        """(3,) the hand point (between the fingertips)."""
        return data.qpos[self._hand_adr : self._hand_adr + 3]

    def finger_opening(self, data: mjx.Data) -> jax.Array:
        """() the gap between the fingertip pads, in [0, 0.08]."""
        return data.qpos[self._finger_adr].sum()
