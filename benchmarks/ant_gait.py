"""How fast the ant can walk under a physics setting: an open-loop gait probe.

    python -m benchmarks.ant_gait [--search 1400] [--seed 0] [--draws 16] [--mjx]

A learned policy can only be as fast as the simulated ant lets it be, and the Ant task
asks for speed: the nearer mode is 20 units of corridor from the start, to be covered in
H = 300 env steps of 0.05 s (at least 1.33 units/s). This probe measures the speed a
simple open-loop gait reaches under each physics setting, so a setting that slows the ant
(an unconverged contact solve lets the feet slip) shows as a shorter path.

The gait is a central pattern generator: motor j gets
a_j(t) = clip(A_j sin(w t dt + phi_j) + c_j, -1, 1), t the env step and dt = 0.05 s, so a
gait is 25 numbers (w, A (8), phi (8), c (8)), in ant.xml's actuator order. `search`
finds a fast one by random search then hill climbing, on an open floor (the ant of
ant.xml in an 11 x 11-cell arena, walls 18 units away) under one physics setting;
`path_lengths` replays a gait from the env's resets (SPEC §8's noise) under each setting
and measures the torso's path, summed over 10-step chords (a gait's heading drifts, so
the path is steadier than the displacement). `--mjx` adds the MJX replay at the env's own
settings, the physics training actually runs.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import mjx

from envs import ant
from envs.base import put_mjx, scan_substeps

H = ant.Ant.horizon
ENV_DT = ant.TIMESTEP * ant.N_SUBSTEPS
CHORD = 10
"""Env steps per chord of the measured path."""
_FREE_ROWS = ("#" + "." * 9 + "#",) * 4
OPEN_ARENA = ("#" * 11, *_FREE_ROWS, "#....S....#", *_FREE_ROWS, "#" * 11)
"""An 11 x 11-cell layout with the start in the middle: the walls are 18 units away."""

FAST_GAIT = np.array([
    8.5032, 1.389, 0.6344, -0.4283, 0.5919, 1.4214, -0.4193, 1.3237, 0.5537,
    6.1225, 5.8179, 4.8759, 8.2427, 2.9209, 6.3203, 5.5341, 4.8634,
    0.2686, 0.1534, -0.0994, 0.0304, 0.141, 0.0793, -0.1879, -0.1948,
], np.float32)  # fmt: skip
"""(25,) the gait `python -m benchmarks.ant_gait --search 1400` finds (seed 0, under RK4
with a converged solve), rounded to 4 decimals: about 22 units of path in H steps there.
tests/test_ant.py replays it."""


def cpg_action(gait: np.ndarray, t) -> np.ndarray:
    """(8,) motor commands of `gait` (25,) at env step t (works on numpy and jax arrays)."""
    xp = jnp if isinstance(gait, jax.Array) else np
    w, amp, phase, offset = gait[0], gait[1:9], gait[9:17], gait[17:25]
    return xp.clip(amp * xp.sin(w * t * ENV_DT + phase) + offset, -1.0, 1.0)


PHYSICS: dict[str, tuple[int, int, str, int] | None] = {
    "env": None,
    "euler_newton1": (1, ant.LS_ITERATIONS, "euler", 1),
    "euler_newton8": (8, ant.LS_ITERATIONS, "euler", 1),
    "euler": (100, 50, "euler", 1),
    "euler_half_dt": (100, 50, "euler", 2),
    "rk4": (100, 50, "rk4", 1),
}
"""name -> (Newton iterations, line-search iterations, integrator, timestep divisor), or
None for envs/ant.py's own setting. The Euler rows integrate without the implicit-damping
pass (`eulerdamp`), as the env did: `euler_newton1` is its setting before 2026-12-02,
`euler_newton8` until 2026-12-04, `euler` a converged solve. `euler_half_dt` halves the
timestep and doubles the substeps (the env step stays 0.05 s). `rk4` is a converged solve
with RK4, the integrator of OUTPACE's ant.xml (timestep 0.01 and 5 substeps, as ours)."""
INTEGRATORS = {"euler": mujoco.mjtIntegrator.mjINT_EULER, "rk4": mujoco.mjtIntegrator.mjINT_RK4}


def open_arena_model(physics: str) -> mujoco.MjModel:
    """The ant on OPEN_ARENA under a named physics setting (see PHYSICS)."""
    if PHYSICS[physics] is None:
        return ant.build_ant_model(OPEN_ARENA)
    iterations, ls_iterations, integrator, dt_divisor = PHYSICS[physics]
    model = ant.build_ant_model(OPEN_ARENA, iterations=iterations, ls_iterations=ls_iterations)
    model.opt.integrator = INTEGRATORS[integrator]
    if integrator == "euler":
        model.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_EULERDAMP
    model.opt.timestep /= dt_divisor
    return model


def substeps(model: mujoco.MjModel) -> int:
    """Physics steps per env step (0.05 s) at the model's timestep."""
    return round(ENV_DT / model.opt.timestep)


def describe(model: mujoco.MjModel) -> str:
    """'<integrator> dt <timestep>, Newton <iterations>/<line-search iterations>' of a model."""
    name = mujoco.mjtIntegrator(model.opt.integrator).name.removeprefix("mjINT_").lower()
    solve = f"Newton {model.opt.iterations}/{model.opt.ls_iterations}"
    return f"{name} dt {model.opt.timestep:g}, {solve}"


def torso_path(model: mujoco.MjModel, gait: np.ndarray, key=None) -> tuple[float, float]:
    """C MuJoCo: (path over H env steps in 10-step chords, final displacement) of the torso,
    from the start pose, or from the env's reset (`ant.reset_qpos_qvel(key)`) given a key."""
    data = mujoco.MjData(model)
    if key is None:
        data.qpos[:] = ant.START_QPOS
    else:
        data.qpos[:], data.qvel[:] = map(np.asarray, ant.reset_qpos_qvel(key))
    start = data.qpos[:2].copy()
    prev, path = start.copy(), 0.0
    for t in range(H):
        data.ctrl[:] = cpg_action(gait, t)
        mujoco.mj_step(model, data, nstep=substeps(model))
        if t % CHORD == CHORD - 1:
            path += float(np.linalg.norm(data.qpos[:2] - prev))
            prev = data.qpos[:2].copy()
    return path, float(np.linalg.norm(data.qpos[:2] - start))


def reset_keys(draws: int, seed: int) -> jax.Array:
    """(draws,) reset keys: the C and MJX replays start from the same states."""
    return jax.random.split(jax.random.PRNGKey(seed), draws)


def path_lengths(model: mujoco.MjModel, gait: np.ndarray, draws: int, seed: int = 0) -> np.ndarray:
    """(draws, 2) torso_path from `draws` env resets (`reset_keys`)."""
    return np.array([torso_path(model, gait, key) for key in reset_keys(draws, seed)])


def mjx_path_lengths(
    model: mujoco.MjModel, gait: np.ndarray, draws: int, seed: int = 0
) -> np.ndarray:
    """(draws, 2) the same measure in MJX, from the same resets, vmapped."""
    mjx_model, template = put_mjx(model)
    gait = jnp.asarray(gait)

    def episode(key):
        qpos, qvel = ant.reset_qpos_qvel(key)
        data = template.replace(qpos=qpos, qvel=qvel)

        def step(d, t):
            d = scan_substeps(
                lambda x: mjx.step(mjx_model, x),
                d.replace(ctrl=cpg_action(gait, t)),
                substeps(model),
            )
            return d, d.qpos[:2]

        _, xy = jax.lax.scan(step, data, jnp.arange(H))
        points = jnp.concatenate([qpos[None, :2], xy[CHORD - 1 :: CHORD]])
        path = jnp.sum(jnp.linalg.norm(jnp.diff(points, axis=0), axis=-1))
        return jnp.stack([path, jnp.linalg.norm(xy[-1] - qpos[:2])])

    return np.asarray(jax.jit(jax.vmap(episode))(reset_keys(draws, seed)))


def search(
    model: mujoco.MjModel, samples: int, seed: int, log: Callable[[str], None] = print
) -> np.ndarray:
    """(25,) the gait with the longest displacement from the start pose (no noise) after
    `samples` trials: 60 random gaits, then Gaussian steps around the best so far."""
    rng = np.random.default_rng(seed)
    best, best_gait = -1.0, None
    for i in range(samples):
        if best_gait is None or i < 60:
            w, amp = rng.uniform(2, 20, 1), rng.uniform(0, 1, 8)
            phase, offset = rng.uniform(0, 2 * np.pi, 8), rng.uniform(-0.3, 0.3, 8)
            gait = np.concatenate([w, amp, phase, offset])
        else:
            scales = np.repeat([1.0, 0.1, 0.3, 0.05], [1, 8, 8, 8])
            gait = best_gait + scales * rng.normal(size=25)
        _, displacement = torso_path(model, gait)
        if displacement > best:
            best, best_gait = displacement, gait
            log(f"  trial {i}: displacement {displacement:.2f} in {H} env steps")
    return best_gait


def _summary(r: np.ndarray) -> str:
    """One line of a (draws, 2) path_lengths result."""
    return f"path {r[:, 0].mean():5.2f} ± {r[:, 0].std():4.2f}, displacement {r[:, 1].mean():5.2f}"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="benchmarks.ant_gait", description=__doc__)
    parser.add_argument(
        "--search", type=int, default=0, help="trials of a new gait search (0: FAST_GAIT)"
    )
    parser.add_argument("--search-physics", default="rk4", help=f"one of {sorted(PHYSICS)}")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--draws", type=int, default=16)
    parser.add_argument(
        "--mjx", action="store_true", help="also replay in MJX at the env's settings"
    )
    args = parser.parse_args(argv)
    problems = []
    if args.search < 0:
        problems.append(f"--search must be >= 0 trials, got {args.search}")
    if args.draws < 1:
        problems.append(f"--draws must be >= 1, got {args.draws}")
    if args.search_physics not in PHYSICS:
        problems.append(
            f"--search-physics must be one of {sorted(PHYSICS)}, got {args.search_physics!r}"
        )
    if problems:
        print(f"error: {problems[0]}", file=sys.stderr)
        return 2
    gait = FAST_GAIT
    if args.search:
        print(f"searching {args.search} gaits under {args.search_physics} (seed {args.seed})")
        gait = search(open_arena_model(args.search_physics), args.search, args.seed)
        print("gait:", np.array2string(gait, precision=4, separator=", ", max_line_width=100))
    print(f"torso path over {H} env steps ({H * ENV_DT:.0f} s), {args.draws} reset draws:")
    for name in PHYSICS:
        model = open_arena_model(name)
        r = path_lengths(model, gait, args.draws, args.seed)
        print(f"  {name:13s} ({describe(model)}): {_summary(r)}")
    if args.mjx:
        model = open_arena_model("env")
        r = mjx_path_lengths(model, gait, args.draws, args.seed)
        print(f"  MJX, env      ({describe(model)}): {_summary(r)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
