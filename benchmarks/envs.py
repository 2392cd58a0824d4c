"""Env steps/s of every environment: MJX at batch 1, 64 and 1024 against C MuJoCo.

    python -m benchmarks.envs [--envs ant sawyer_push ...] [--batch-sizes 1 64 1024]
                              [--repeats 3] [--write]

MJX: `jit(lax.scan over env steps of vmap(env.step))` with uniform random actions, timed
after compilation (best of `--repeats`); one env step is the env's whole step (the Ant and
Sawyer run 5 physics substeps, the point mazes their kinematic move). Each (env, batch)
runs in its own child process with a time limit: XLA's CPU runtime deadlocks (not
always, but mostly) on the Sawyer step vmapped 512 wide or more (every thread idle in a
futex wait, no CPU used; jax 0.10.2; 256 wide never hung), so a child that times out is
re-run stepping the batch as a `lax.map` over vmapped chunks of `FALLBACK_CHUNK` envs,
and its row is marked. The cause is jaxlib's batched Cholesky in MJX's Newton solver (see
`d2c_jax.core.rollout.MAX_CPU_ENV_BATCH`, which caps the package's own episode loop).

C MuJoCo: `mujoco.rollout` on the same MjModel, one thread and all threads, the same
number of env steps (x substeps), open loop with the same kind of controls (Ant: uniform
random torques held for an env step; Sawyer: finger targets and a mocap target doing a
random walk of 0.01 m per env step, interpolated per substep). The point mazes have no
MuJoCo dynamics (the pose is computed in JAX and written into qpos; SPEC §8), so they
have no C MuJoCo column. `--write` replaces the "Environments" section of RESULTS.md.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

import jax
import mujoco
import numpy as np
from mujoco import rollout as mj_rollout

import envs
from benchmarks import results

STEPS = {1: 200, 64: 100}
"""Env steps per env in one timed run, by batch size (larger batches: 20)."""
CHILD_TIMEOUT_S = 240
FALLBACK_CHUNK = 256


def steps_for(batch: int) -> int:
    return STEPS.get(batch, 20)


# --- MJX (in a child process) --------------------------------------------------------------
def chunked_step(env, chunk: int):
    """vmap(env.step) over a batch B, as a lax.map over B / chunk vmapped chunks."""

    def step(state, action):
        batch = action.shape[0]
        split = lambda x: x.reshape((batch // chunk, chunk) + x.shape[1:])  # noqa: E731
        merge = lambda x: x.reshape((batch,) + x.shape[2:])  # noqa: E731
        inputs = jax.tree.map(split, (state, action))
        return jax.tree.map(merge, jax.lax.map(lambda sa: jax.vmap(env.step)(*sa), inputs))

    return step


def mjx_rate(env_name: str, batch: int, steps: int, repeats: int, chunk: int = 0) -> dict:
    """{'steps_per_s', 'compile_s'} of `batch` envs stepping `steps` times under MJX.

    chunk > 0 steps the batch as chunks of `chunk` envs (see the module docstring).
    """
    env = envs.make(env_name)
    step = chunked_step(env, chunk) if 0 < chunk < batch else jax.vmap(env.step)

    def run(state, key):
        def body(state, k):
            action = jax.random.uniform(k, (batch, env.action_dim), minval=-1.0, maxval=1.0)
            return step(state, action), None

        state, _ = jax.lax.scan(body, state, jax.random.split(key, steps))
        return state

    key = jax.random.key(0)
    state = jax.jit(jax.vmap(env.reset))(jax.random.split(key, batch))
    start = time.perf_counter()
    compiled = jax.jit(run).lower(state, key).compile()
    compile_s = time.perf_counter() - start
    jax.block_until_ready(compiled(state, key))  # warm-up
    best = np.inf
    for i in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(compiled(state, jax.random.key(i + 1)))
        best = min(best, time.perf_counter() - start)
    return {"steps_per_s": batch * steps / best, "compile_s": compile_s}


def mjx_rate_in_child(env_name: str, batch: int, steps: int, repeats: int) -> dict:
    """mjx_rate in a fresh process; on a time-out, once more in chunks of FALLBACK_CHUNK.

    Returns mjx_rate's dict plus 'chunked' (bool); steps_per_s is NaN if both hang.
    """
    for chunk in (0, FALLBACK_CHUNK) if batch > FALLBACK_CHUNK else (0,):
        cmd = [sys.executable, "-m", "benchmarks.envs", "--child", env_name, str(batch)]
        cmd += [str(steps), str(repeats), str(chunk)]
        try:
            out = subprocess.run(cmd, capture_output=True, text=True, timeout=CHILD_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            continue
        if out.returncode != 0:
            raise RuntimeError(f"benchmark child failed: {' '.join(cmd)}\n{out.stderr[-2000:]}")
        return {**json.loads(out.stdout.strip().splitlines()[-1]), "chunked": chunk > 0}
    return {"steps_per_s": float("nan"), "compile_s": float("nan"), "chunked": True}


# --- C MuJoCo ------------------------------------------------------------------------------
def start_states(model: mujoco.MjModel, batch: int, reset) -> np.ndarray:
    """(batch, nstate) full physics states, each made by reset(data) on a fresh MjData."""
    data = mujoco.MjData(model)
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    state = np.empty((batch, mujoco.mj_stateSize(model, spec)))
    for i in range(batch):
        reset(data)
        mujoco.mj_getState(model, data, state[i], spec)
    return state


def ant_c_inputs(env, batch: int, steps: int, rng: np.random.Generator):
    """Ant: the env's reset states (batch, nstate) and held torques (batch, steps*5, 8)."""
    from envs import ant

    model = env.mj_model
    keys = jax.random.split(jax.random.key(int(rng.integers(2**31))), batch)
    qpos, qvel = map(np.asarray, jax.vmap(ant.reset_qpos_qvel)(keys))  # (batch, 15), (batch, 14)
    resets = iter(zip(qpos, qvel, strict=True))

    def reset(data):
        mujoco.mj_resetData(model, data)
        data.qpos[:], data.qvel[:] = next(resets)

    state = start_states(model, batch, reset)
    torques = rng.uniform(-1.0, 1.0, (batch, steps, 1, model.nu))
    control = np.repeat(torques, ant.N_SUBSTEPS, axis=2).reshape(batch, -1, model.nu)
    return state, control, mujoco.mjtState.mjSTATE_CTRL


def sawyer_c_inputs(env, batch: int, steps: int, rng: np.random.Generator):
    """Sawyer: start states with peg noise and (finger ctrl 2 + mocap xyz 3) per substep."""
    from envs import sawyer_peg as sp

    def reset(data):
        mujoco.mj_resetDataKeyframe(env.mj_model, data, 0)
        data.qpos[5:7] += rng.uniform(-sp.PEG_NOISE, sp.PEG_NOISE, 2)

    state = start_states(env.mj_model, batch, reset)
    actions = rng.uniform(-1.0, 1.0, (batch, steps, 4))
    target = np.broadcast_to(sp.HAND_START, (batch, 3)).copy()
    mocap = np.empty((batch, steps, sp.N_SUBSTEPS, 3))
    frac = (np.arange(sp.N_SUBSTEPS) + 1.0) / sp.N_SUBSTEPS
    for t in range(steps):
        new = np.clip(target + sp.MOVE_SCALE * actions[:, t, :3], sp.HAND_LOW, sp.HAND_HIGH)
        mocap[:, t] = target[:, None] + frac[None, :, None] * (new - target)[:, None]
        target = new
    ctrl = np.repeat(0.5 * sp.FINGER_OPEN * (1.0 - actions[..., 3:]), 2, axis=-1)
    ctrl = np.repeat(ctrl[:, :, None], sp.N_SUBSTEPS, axis=2)
    control = np.concatenate([ctrl, mocap], axis=-1).reshape(batch, steps * sp.N_SUBSTEPS, 5)
    return state, control, mujoco.mjtState.mjSTATE_CTRL | mujoco.mjtState.mjSTATE_MOCAP_POS


C_INPUTS = {
    "ant": ant_c_inputs,
    "sawyer_push": sawyer_c_inputs,
    "sawyer_pick_place": sawyer_c_inputs,
}
"""Envs with MuJoCo dynamics -> their open-loop C MuJoCo workload."""


def c_rate(env, env_name: str, batch: int, steps: int, nthread: int, repeats: int) -> float:
    """Env steps/s of C MuJoCo (`mujoco.rollout`, `nthread` threads) on the same work."""
    state, control, control_spec = C_INPUTS[env_name](env, batch, steps, np.random.default_rng(0))
    datas = [mujoco.MjData(env.mj_model) for _ in range(nthread)]
    kwargs = dict(control_spec=int(control_spec), persistent_pool=nthread > 1)
    mj_rollout.rollout(env.mj_model, datas, state[:1], control[:1, :10], **kwargs)  # warm-up
    best = np.inf
    for _ in range(repeats):
        start = time.perf_counter()
        mj_rollout.rollout(env.mj_model, datas, state, control, **kwargs)
        best = min(best, time.perf_counter() - start)
    return batch * steps / best


# --- the table -----------------------------------------------------------------------------
def run(env_names, batch_sizes, repeats: int) -> str:
    """Measures every (env, batch); returns the markdown body of the section."""
    nthreads = os.cpu_count() or 1
    rows = [
        "| env | batch | env steps timed | MJX steps/s | MJX compile (s) | C 1 thread | "
        f"C {nthreads} threads | MJX / C {nthreads} threads |",
        "|---|---|---|---|---|---|---|---|",
    ]
    chunked_rows = 0
    for name in env_names:
        env = envs.make(name)
        for batch in batch_sizes:
            steps = steps_for(batch)
            mjx = mjx_rate_in_child(name, batch, steps, repeats)
            mark = " †" if mjx["chunked"] else ""
            chunked_rows += bool(mark)
            cells = [name, str(batch), f"{batch * steps:,}"]
            cells += [f"{mjx['steps_per_s']:,.0f}{mark}", f"{mjx['compile_s']:.0f}"]
            if name in C_INPUTS:
                c1 = c_rate(env, name, batch, steps, 1, repeats)
                cn = c_rate(env, name, batch, steps, nthreads, repeats)
                cells += [f"{c1:,.0f}", f"{cn:,.0f}", f"{mjx['steps_per_s'] / cn:.2f}"]
            else:
                cells += ["n/a", "n/a", "n/a"]
            rows.append("| " + " | ".join(cells) + " |")
            print(rows[-1], flush=True)
    notes = [
        f"Command: `python -m benchmarks.envs --write` ({time.strftime('%Y-%m-%d')}).",
        f"Hardware: {results.hardware()}. jax {jax.__version__}, mujoco {mujoco.__version__};"
        f" load average {os.getloadavg()[0]:.1f} at the end.",
        "",
        "\n".join(rows),
        "",
        "n/a: the point mazes have no MuJoCo dynamics (kinematic move in JAX, SPEC §8).",
    ]
    if chunked_rows:
        notes.append(
            f"†: the plain vmap over the whole batch deadlocked in XLA's CPU runtime (no CPU "
            f"used for {CHILD_TIMEOUT_S} s; jax {jax.__version__}); measured as a `lax.map` "
            f"over vmapped chunks of {FALLBACK_CHUNK} envs, the same env steps."
        )
    return "\n".join(notes)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--envs", nargs="+", default=list(envs.ENV_NAMES), choices=envs.ENV_NAMES)
    parser.add_argument("--batch-sizes", nargs="+", type=int, default=[1, 64, 1024])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--write", action="store_true", help="update benchmarks/RESULTS.md")
    parser.add_argument("--child", nargs=5, metavar=("ENV", "BATCH", "STEPS", "REPEATS", "CHUNK"))
    args = parser.parse_args(argv)
    if args.child:
        name, *sizes = args.child
        print(json.dumps(mjx_rate(name, *map(int, sizes))))
        return 0
    results.report("Environments", run(args.envs, args.batch_sizes, args.repeats), args.write)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
