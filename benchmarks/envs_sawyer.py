"""Env steps/s of the Sawyer peg envs: MJX against C MuJoCo on the same model.

    python benchmarks/envs_sawyer.py [--tasks push pick_place] [--batch-sizes 1 64 1024]
                                     [--write]

MJX: `jit(lax.scan over env steps of vmap(env.step))` with uniform random actions, timed
after compilation (best of `--repeats`); one env step = 5 physics substeps plus the env's
action mapping and observation. C MuJoCo: `mujoco.rollout` on the same MjModel with one
thread and with all threads, the same number of env steps (x 5 substeps), driven open loop
by the same kind of controls: finger targets and a mocap target doing a random walk of
0.01 m per env step (interpolated per substep, clipped to the hand bounds). `--write`
replaces the section "## Environments: sawyer" of benchmarks/RESULTS.md with the table.
"""

from __future__ import annotations

import argparse
import os
import pathlib
import platform
import subprocess
import time

import jax
import mujoco
import numpy as np
from mujoco import rollout as mj_rollout

import envs
from envs import sawyer_peg

RESULTS = pathlib.Path(__file__).with_name("RESULTS.md")
SECTION = "## Environments: sawyer"
STEPS = {1: 200, 64: 100, 1024: 20}
"""Env steps per env in one timed run, by batch size (others: 20)."""


def mjx_rate(env, batch: int, steps: int, repeats: int) -> tuple[float, float]:
    """(env steps/s, compile seconds) of `batch` envs stepping `steps` times under MJX."""

    def run(state, key):
        def body(state, k):
            action = jax.random.uniform(k, (batch, 4), minval=-1.0, maxval=1.0)
            return jax.vmap(env.step)(state, action), None

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
    return batch * steps / best, compile_s


def c_inputs(model: mujoco.MjModel, batch: int, steps: int, seed: int = 0):
    """Initial states (batch, nstate) and open-loop controls (batch, 5 steps, 2 + 3)."""
    rng = np.random.default_rng(seed)
    data = mujoco.MjData(model)
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    state = np.empty((batch, mujoco.mj_stateSize(model, spec)))
    for i in range(batch):
        mujoco.mj_resetDataKeyframe(model, data, 0)
        data.qpos[5:7] += rng.uniform(-sawyer_peg.PEG_NOISE, sawyer_peg.PEG_NOISE, 2)
        mujoco.mj_getState(model, data, state[i], spec)
    n_sub = sawyer_peg.N_SUBSTEPS
    actions = rng.uniform(-1.0, 1.0, (batch, steps, 4))
    target = np.broadcast_to(sawyer_peg.HAND_START, (batch, 3)).copy()
    mocap = np.empty((batch, steps, n_sub, 3))
    for t in range(steps):
        new = np.clip(target + sawyer_peg.MOVE_SCALE * actions[:, t, :3],
                      sawyer_peg.HAND_LOW, sawyer_peg.HAND_HIGH)  # fmt: skip
        frac = (np.arange(n_sub) + 1.0) / n_sub
        mocap[:, t] = target[:, None] + frac[None, :, None] * (new - target)[:, None]
        target = new
    ctrl = np.repeat(0.5 * sawyer_peg.FINGER_OPEN * (1.0 - actions[..., 3:]), 2, axis=-1)
    ctrl = np.repeat(ctrl[:, :, None], n_sub, axis=2)
    control = np.concatenate([ctrl, mocap], axis=-1).reshape(batch, steps * n_sub, 5)
    return state, control


def c_rate(model: mujoco.MjModel, batch: int, steps: int, nthread: int, repeats: int) -> float:
    """Env steps/s of C MuJoCo (`mujoco.rollout`, `nthread` threads) on the same work."""
    state, control = c_inputs(model, batch, steps)
    datas = [mujoco.MjData(model) for _ in range(nthread)]
    spec = mujoco.mjtState.mjSTATE_CTRL | mujoco.mjtState.mjSTATE_MOCAP_POS
    kwargs = dict(control_spec=int(spec), persistent_pool=nthread > 1)
    mj_rollout.rollout(model, datas, state[:1], control[:1, :10], **kwargs)  # warm-up
    best = np.inf
    for _ in range(repeats):
        start = time.perf_counter()
        mj_rollout.rollout(model, datas, state, control, **kwargs)
        best = min(best, time.perf_counter() - start)
    return batch * steps / best


def hardware() -> str:
    """One line naming the CPU (from lscpu), the core count and the JAX backend."""
    try:
        out = subprocess.run(["lscpu"], capture_output=True, text=True, check=True).stdout
        name = next(ln.split(":", 1)[1].strip() for ln in out.splitlines() if "Model name" in ln)
    except (OSError, subprocess.CalledProcessError, StopIteration):
        name = platform.processor() or "unknown CPU"
    devices = ", ".join(str(d) for d in jax.devices())
    return f"{name}, {os.cpu_count()} cores; JAX devices: {devices}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--tasks", nargs="+", default=["push", "pick_place"])
    parser.add_argument("--batch-sizes", nargs="+", type=int, default=[1, 64, 1024])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--write", action="store_true", help="update benchmarks/RESULTS.md")
    args = parser.parse_args()

    nthreads = os.cpu_count() or 1
    rows = [
        "| env | batch | env steps | MJX steps/s | MJX compile (s) | C 1 thread | "
        f"C {nthreads} threads | MJX / C {nthreads} threads |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for task in args.tasks:
        env = envs.make(f"sawyer_{task}")
        for batch in args.batch_sizes:
            steps = STEPS.get(batch, 20)
            mjx_sps, compile_s = mjx_rate(env, batch, steps, args.repeats)
            c1 = c_rate(env.mj_model, batch, steps, 1, args.repeats)
            cn = c_rate(env.mj_model, batch, steps, nthreads, args.repeats)
            rows.append(
                f"| sawyer_{task} | {batch} | {batch * steps} | {mjx_sps:,.0f} | "
                f"{compile_s:.0f} | {c1:,.0f} | {cn:,.0f} | {mjx_sps / cn:.2f} |"
            )
            print(rows[-1], flush=True)
    versions = (
        f"jax {jax.__version__}, mujoco {mujoco.__version__}, "
        f"load average {os.getloadavg()[0]:.1f} at the end"
    )
    table = "\n".join(rows)
    print(f"\n{hardware()}\n{versions}\n\n{table}")
    if args.write:
        write_section(table, f"{hardware()}; {versions}.")


def write_section(table: str, context: str) -> None:
    """Replaces (or appends) this benchmark's section of RESULTS.md, leaving the rest."""
    text = RESULTS.read_text() if RESULTS.exists() else "# Benchmark results\n"
    body = (
        f"{SECTION}\n\n`python benchmarks/envs_sawyer.py --write` "
        f"({time.strftime('%Y-%m-%d')}). {context}\n\n{table}\n"
    )
    start = text.find(SECTION)
    if start < 0:
        text = text.rstrip("\n") + "\n\n" + body
    else:
        end = text.find("\n## ", start + len(SECTION))
        rest = "" if end < 0 else text[end:]
        text = text[:start] + body + rest
    RESULTS.write_text(text)


if __name__ == "__main__":
    main()
