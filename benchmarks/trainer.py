"""Whole-trainer benchmarks: throughput, seed scaling and memory.

    python -m benchmarks.trainer [--parts throughput seeds sweep memory curriculum]
    python -m benchmarks.trainer --parts seeds --env ant --preset paper --seeds 1 8

prints the numbers; `python -m benchmarks.run` writes them into RESULTS.md.

Every number is the steady state of `agent.jit_step`, the program `train.py`
runs: compiled ahead of time, one untimed iteration, then the best of `repeats` timed
iterations (the mean is within a few % of it on an idle machine).

- throughput: env steps/s on `medium_maze` at SB3's settings (3x512, batch 512, one SAC
  update per env step, actor and target every update), for SAC+HER alone (sparse reward,
  no curriculum, no classifier updates) and for full D2C (Table 3 classifier, matching
  curriculum, intrinsic reward); also at 2x256 with batch 256. 4 parallel episodes per
  iteration (400 env steps, 400 updates) keep an iteration short on a CPU; the update
  count per env step is what sets the rate.
- seeds: the `quick` preset, 1, 4 and 16 vmapped seeds (or `--env`, `--preset`,
  `--seeds`); seconds per iteration, env steps/s per seed, relative to one seed and to
  running the seeds one after another (n x one seed).
- sweep: a sweep of 1, 4 and 16 runs (lambda values of the `quick` preset) as one
  program, against the same runs one after another: compile + 10 iterations each.
- memory: the `paper` preset with its 3e6-transition buffer, in a fresh process: peak
  resident memory after init, after compiling, and after one executed iteration (M set to
  one SAC block: the buffers and per-update temporaries are those of the real preset),
  with XLA's own memory analysis of the compiled iteration.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import subprocess
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

import envs
from benchmarks.sac_update import SIZES
from d2c_jax import config
from d2c_jax.core import sac
from d2c_jax.curricula import curriculum
from d2c_jax.training import agent as trainer


def sb3_settings(cfg: config.TrainConfig, hidden, batch: int) -> config.TrainConfig:
    """SB3's schedule: one update per env step, actor and target every update."""
    return dataclasses.replace(
        cfg,
        num_envs=4,
        utd=1.0,
        sac=dataclasses.replace(
            cfg.sac,
            hidden_sizes=hidden,
            batch_size=batch,
            actor_update_every=1,
            target_update_every=1,
        ),
    )


def sac_her_only(cfg: config.TrainConfig) -> config.TrainConfig:
    """D2C's parts switched off: sparse reward, goals from the desired set, no classifier."""
    return dataclasses.replace(
        cfg,
        reward="sparse",
        curriculum=dataclasses.replace(cfg.curriculum, variant="none"),
        classifier=dataclasses.replace(cfg.classifier, iters=0),
    )


class TimedRun:
    """The compiled train step of `cfg`, ready to time one matching cycle at a time.

    Compiles `agent.jit_step` ahead of time, runs the warm-up iteration (random actions;
    it also trains), then steps on to a matching iteration, so that every timed round is
    one whole matching cycle (`schedule.rematch_every` iterations: the curriculum matches
    once per 2000 env steps) and an iteration's share of the matching is in its time.
    """

    def __init__(self, cfg: config.TrainConfig):
        agent = trainer.Agent(cfg, envs.make(cfg.env))
        self.schedule = agent.schedule
        self.num_seeds = cfg.num_seeds
        ts = agent.init_seeds()
        start = time.perf_counter()
        self.step = trainer.jit_step(agent).lower(ts).compile()
        self.compile_s = time.perf_counter() - start
        ts, _ = self.step(ts)
        jax.block_until_ready(ts)
        while int(ts.iteration.reshape(-1)[0]) % self.schedule.rematch_every:
            ts, _ = self.step(ts)
        self.ts = ts

    def round_seconds(self) -> float:
        """Seconds per iteration over one timed matching cycle (the state moves on)."""
        cycle = self.schedule.rematch_every
        start = time.perf_counter()
        for _ in range(cycle):
            self.ts, metrics = self.step(self.ts)
        jax.block_until_ready((self.ts, metrics))
        return (time.perf_counter() - start) / cycle

    def env_steps_per_s(self) -> float:
        """Env steps/s (all seeds) of one timed round."""
        return self.num_seeds * self.schedule.env_steps / self.round_seconds()

    @property
    def updates_per_env_step(self) -> float:
        """SAC updates per env step of the schedule (1.0 at SB3's settings)."""
        return self.schedule.sac_updates / self.schedule.env_steps


def iteration_seconds(cfg: config.TrainConfig, repeats: int = 2) -> tuple[float, float]:
    """(best seconds per iteration over `repeats` rounds, compile seconds) of the vmapped
    train step (`TimedRun`)."""
    run = TimedRun(cfg)
    return min(run.round_seconds() for _ in range(repeats)), run.compile_s


def throughput_configs(size: str, env_name: str = "medium_maze") -> dict[str, config.TrainConfig]:
    """Our two rows of the throughput table at SB3's settings and SIZES[size]:
    'SAC+HER' (D2C's parts off) and 'D2C'."""
    hidden, batch = SIZES[size]
    cfg = sb3_settings(config.preset(env_name, "paper"), hidden, batch)
    return {"SAC+HER": sac_her_only(cfg), "D2C": cfg}


def throughput_rows(
    env_name: str = "medium_maze", repeats: int = 2
) -> dict[tuple[str, str], float]:
    """Env steps/s of d2c_jax at SB3's settings: (size of SIZES, 'SAC+HER' | 'D2C') -> the
    best of `repeats` rounds; the rows of a size alternate round by round, so both see the
    same machine."""
    out = {}
    for size in SIZES:
        configs = throughput_configs(size, env_name)
        runs = {variant: TimedRun(cfg) for variant, cfg in configs.items()}
        rates = [alternate_rounds(runs) for _ in range(repeats)]
        for variant in runs:
            out[size, variant] = max(r[variant] for r in rates)
        print(size, out, flush=True)
    return out


def alternate_rounds(runs: dict[str, TimedRun]) -> dict[str, float]:
    """One timed round of each run, one after the other: name -> env steps/s."""
    return {name: run.env_steps_per_s() for name, run in runs.items()}


def seed_scaling(env_name: str = "medium_maze", seeds=(1, 4, 16), preset: str = "quick") -> str:
    """Seconds per iteration of `preset` on `env_name` with 1..N vmapped seeds, and the
    env steps/s each seed gets (issue 15 §6 runs it as `--env ant --preset paper`)."""
    rows = [
        "| vmapped seeds | s / iteration | compile (s) | env steps/s per seed | vs 1 seed | "
        "vs the seeds run one after another |",
        "|---|---|---|---|---|---|",
    ]
    one = None
    horizon = envs.make(env_name).horizon
    for n in seeds:
        cfg = dataclasses.replace(config.preset(env_name, preset), num_seeds=n)
        seconds, compile_s = iteration_seconds(cfg)
        per_seed = trainer.make_schedule(cfg, horizon).env_steps / seconds
        one = one or seconds
        rows.append(
            f"| {n} | {seconds:.2f} | {compile_s:.0f} | {per_seed:,.0f} | {seconds / one:.2f}x | "
            f"{seconds / (n * one):.2f} of the time |"
        )
        print(rows[-1], flush=True)
    return "\n".join(rows)


def curriculum_share(env_name: str = "medium_maze", repeats: int = 20) -> str:
    """The curriculum step (Eq. 7 cost matrix + auction + goal noise) against an iteration.

    One seed of the `quick` preset (K = 20 slots, P = 100 pool episodes, like the paper):
    `curriculum.propose` jitted alone on a full pool of random states inside the goal
    bounds (so the matching has real work), median of `repeats` calls, over the seconds of
    a whole quick-preset iteration (the smallest iteration of any preset here).
    """
    cfg = config.preset(env_name, "quick")
    env = envs.make(env_name)
    agent = trainer.Agent(cfg, env)
    ts = agent.init(jax.random.key(0))
    cur = cfg.curriculum
    shape = (cur.pool_size, env.horizon + 1)
    pool = env.sample_uniform_goals(jax.random.key(1), shape[0] * shape[1])
    pool = pool.reshape(shape + (env.goal_dim,))
    start = jnp.asarray(env.start_goal)

    @jax.jit
    def propose(key):
        return curriculum.propose(
            cur, env, agent.classifier_net, ts.classifier.params, pool,
            jnp.ones(cur.pool_size, bool), start, key, gamma=cfg.sac.gamma,
        )  # fmt: skip

    jax.block_until_ready(propose(jax.random.key(2)))
    times = []
    for i in range(repeats):
        begin = time.perf_counter()
        jax.block_until_ready(propose(jax.random.key(3 + i)))
        times.append(time.perf_counter() - begin)
    propose_s = float(np.median(times))
    iteration_s, _ = iteration_seconds(cfg)
    return (
        f"Curriculum step (Eq. 7 cost matrix for K = {cur.n_slots}, P = {cur.pool_size}, "
        f"then the auction) on `{env_name}`: **{1e3 * propose_s:.1f} ms**, "
        f"{100 * propose_s / iteration_s:.2f}% of a `quick` iteration ({iteration_s:.2f} s; "
        "target: at most 2%)."
    )


# --- memory (child process) ----------------------------------------------------------------
def peak_rss_gib() -> float:
    """This process's peak resident memory (VmHWM; unlike ru_maxrss, reset by exec, so a
    child does not inherit its parent's peak)."""
    with open("/proc/self/status") as status:
        line = next(ln for ln in status if ln.startswith("VmHWM:"))
    return int(line.split()[1]) / 2**20


def memory_child(env_name: str) -> dict:
    cfg = config.preset(env_name, "paper")
    env = envs.make(env_name)
    # One SAC block per iteration: the same buffers and per-update temporaries.
    cfg = dataclasses.replace(cfg, utd=sac.block_size(cfg.sac) / (cfg.num_envs * env.horizon))
    agent = trainer.Agent(cfg, env)
    ts = agent.init_seeds()
    jax.block_until_ready(ts)
    out = {
        "replay_gib": sum(x.nbytes for x in jax.tree.leaves(ts.replay)) / 2**30,
        "state_gib": sum(x.nbytes for x in jax.tree.leaves(ts)) / 2**30,
        "after_init_gib": peak_rss_gib(),
    }
    compiled = trainer.jit_step(agent).lower(ts).compile()
    out["after_compile_gib"] = peak_rss_gib()
    analysis = compiled.memory_analysis()
    out["xla_temp_gib"] = getattr(analysis, "temp_size_in_bytes", float("nan")) / 2**30
    ts, metrics = compiled(ts)
    jax.block_until_ready((ts, metrics))
    out["after_iteration_gib"] = peak_rss_gib()
    return out


def memory_table(env_names=("medium_maze", "ant")) -> str:
    rows = [
        "| env (paper preset) | replay buffer (GiB) | whole TrainState (GiB) | XLA temporaries "
        "(GiB) | peak RSS after init | after compile | after one iteration |",
        "|---|---|---|---|---|---|---|",
    ]
    for name in env_names:
        cmd = [sys.executable, "-m", "benchmarks.trainer", "--memory-child", name]
        out = subprocess.run(cmd, capture_output=True, text=True, check=True)
        m = json.loads(out.stdout.strip().splitlines()[-1])
        rows.append(
            f"| {name} | {m['replay_gib']:.2f} | {m['state_gib']:.2f} | {m['xla_temp_gib']:.2f} "
            f"| {m['after_init_gib']:.2f} GiB | {m['after_compile_gib']:.2f} GiB | "
            f"{m['after_iteration_gib']:.2f} GiB |"
        )
        print(rows[-1], flush=True)
    return "\n".join(rows)


def sweep_arms(n: int) -> tuple:
    """`n` values of the diversification weight lambda (the paper's ablation field)."""
    return (("classifier.diversity_weight", tuple(float(v) for v in np.linspace(0, 2, n))),)


def sweep_scaling(
    env_name: str = "medium_maze", runs=(1, 4, 16), preset: str = "quick", iterations: int = 10
) -> str:
    """Wall-clock of a sweep of n runs (n lambda values, one program) against the same n
    runs done one after another, each a compile plus `iterations` iterations (issue 13).

    One after another, every run is a process of its own: n x (one run's compile + its
    iterations), with one run's numbers measured here. The sweep pays one compile.
    """
    rows = [
        f"| runs | sweep: compile + {iterations} iterations (s) | one after another (s) | "
        "sweep / one after another |",
        "|---|---|---|---|",
    ]
    single = None
    for n in runs:
        cfg = dataclasses.replace(config.preset(env_name, preset), sweep=sweep_arms(n))
        seconds, compile_s = iteration_seconds(cfg)
        wall = compile_s + iterations * seconds
        single = single or wall
        rows.append(f"| {n} | {wall:.0f} | {n * single:.0f} | {wall / (n * single):.2f} |")
        print(rows[-1], flush=True)
    return "\n".join(rows)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--parts", nargs="+", default=["throughput", "seeds", "memory"],
        choices=["throughput", "seeds", "sweep", "memory", "curriculum"],
    )  # fmt: skip
    parser.add_argument("--env", default="medium_maze", help="env of the seeds part")
    parser.add_argument("--preset", default="quick", help="preset of the seeds part")
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 4, 16])
    parser.add_argument("--memory-child", metavar="ENV", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.memory_child:
        print(json.dumps(memory_child(args.memory_child)))
        return 0
    parts = {
        "throughput": lambda: "\n".join(
            f"{variant} {size}: {rate:,.1f} env steps/s"
            for (size, variant), rate in throughput_rows().items()
        ),
        "seeds": lambda: seed_scaling(args.env, tuple(args.seeds), args.preset),
        "sweep": lambda: sweep_scaling(args.env, tuple(args.seeds), args.preset),
        "memory": memory_table,
        "curriculum": curriculum_share,
    }
    for part in args.parts:
        print(f"{part}:\n{parts[part]()}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
