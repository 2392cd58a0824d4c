"""Where one training iteration spends its time, per environment (issue 15 §3).

    python -m benchmarks.profile [--envs medium_maze ant ...] [--preset quick]

For each env, the `quick` preset's iteration is split into the parts `train_iteration`
is made of, each compiled alone and timed on a replay buffer filled by real iterations:

- env steps: `num_envs` episodes of H steps with the actor, goals held (no goal choice);
- goal choice: `Agent.collect_episodes` (post-success goals from the classifier, SPEC
  §6) minus the above;
- SAC updates: the iteration's M updates with their HER batches and one-step classifier
  rewards;
- n-step rewards: with `her.n_step` = n > 1, the same updates with n-step returns minus
  the above: the n - 1 further classifier calls per sampled row (0 when n = 1);
- classifier updates: its Eq. 5 updates;
- curriculum: one matching (Eq. 7 costs + auction), divided by the iterations it serves;
- evaluation: one SPEC §7 evaluation (`eval_episodes` per mode, deterministic policy),
  divided by the iterations between evaluations. It is outside the train step, so it is
  not in "iteration"; "env steps/s" counts it, as a user's run does.

Each part is the best of `repeats` timed calls after one untimed call; the whole
iteration is `benchmarks.trainer.iteration_seconds` (a whole matching cycle). Parts run
alone lose the overlap and fusion of the whole program, so "other" (whole minus the sum)
can be negative; it is reported, not hidden.
"""

from __future__ import annotations

import argparse
import dataclasses
import time

import jax
import jax.numpy as jnp

import envs
from benchmarks.trainer import iteration_seconds
from d2c_jax import config
from d2c_jax.core import rollout, sac
from d2c_jax.training import agent as trainer


def best_seconds(fn, args, repeats: int) -> float:
    """Best wall time of `fn(*args)` over `repeats` calls, after one untimed call."""
    jax.block_until_ready(fn(*args))
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(fn(*args))
        best = min(best, time.perf_counter() - start)
    return best


def filled_state(cfg: config.TrainConfig, env, iterations: int):
    """One seed's TrainState after `iterations` real iterations (warm-up first), so the
    buffer, classifier and curriculum hold real data; the seed axis is removed."""
    agent = trainer.Agent(cfg, env)
    ts = agent.init_seeds()
    step = trainer.jit_step(agent)
    for _ in range(iterations):
        ts, _ = step(ts)
    return agent, jax.tree.map(lambda x: x[0], ts)


def part_seconds(cfg: config.TrainConfig, env, repeats: int = 3) -> dict[str, float]:
    """Seconds per iteration of each part of the `cfg` iteration on `env` (one seed)."""
    agent, ts = filled_state(cfg, env, iterations=3)
    sched = agent.schedule
    key = jax.random.key(1)
    goals = agent.env_goals(ts, ts.curriculum_goals)
    collect = jax.jit(lambda ts, key: agent.collect_episodes(ts, goals, jnp.asarray(False), key))

    def collect_held_goals(ts, key):
        actor = agent.policy(ts.sac)
        keep_goal = lambda achieved, key: achieved  # noqa: E731  (a free "choice")
        switch_every = cfg.curriculum.post_success_switch_every
        return rollout.collect(env, actor, keep_goal, goals, cfg.num_envs, key, switch_every)

    n_blocks = sched.sac_updates // sac.block_size(cfg.sac)

    def sac_seconds(sac_agent: trainer.Agent) -> float:
        updates = jax.jit(lambda ts, key: sac_agent.sac_blocks(ts, n_blocks, key))
        return best_seconds(updates, (ts, key), repeats)

    classifier_updates = jax.jit(
        lambda ts, key: jax.lax.scan(
            agent.classifier_update, ts, jax.random.split(key, sched.classifier_updates)
        )
    )
    # A matching is due at iteration 0 of its cycle; it serves `rematch_every` iterations.
    due = ts.replace(iteration=jnp.zeros_like(ts.iteration))
    matching = jax.jit(agent.curriculum_goals)
    held = best_seconds(jax.jit(collect_held_goals), (ts, key), repeats)
    if cfg.her.n_step == 1:
        one_step_updates = n_step_updates = sac_seconds(agent)
    else:
        one_step_cfg = dataclasses.replace(cfg, her=dataclasses.replace(cfg.her, n_step=1))
        one_step_updates = sac_seconds(trainer.Agent(one_step_cfg, env))
        n_step_updates = sac_seconds(agent)
    parts = {
        "env steps": held,
        "goal choice": best_seconds(collect, (ts, key), repeats) - held,
        "SAC updates": one_step_updates,
        "n-step rewards": n_step_updates - one_step_updates,
        "classifier updates": best_seconds(classifier_updates, (ts, key), repeats),
        "curriculum": best_seconds(matching, (due, key), repeats) / sched.rematch_every,
    }
    return parts


def profile_row(env_name: str, preset: str = "quick") -> dict:
    """Parts, whole iteration and env steps/s of `preset` on `env_name`."""
    cfg = config.preset(env_name, preset)
    env = envs.make(env_name)
    parts = part_seconds(cfg, env)
    whole, _ = iteration_seconds(cfg)
    sched = trainer.make_schedule(cfg, env.horizon)
    evaluation = evaluation_seconds(cfg, env) / sched.eval_every
    return {
        "env": env_name,
        "parts": parts,
        "whole": whole,
        "other": whole - sum(parts.values()),
        "evaluation": evaluation,
        "env_steps_per_s": sched.env_steps / (whole + evaluation),
        "schedule": sched,
    }


def evaluation_seconds(cfg: config.TrainConfig, env, repeats: int = 3) -> float:
    """Seconds of one scheduled evaluation of a fresh policy (its cost does not depend
    on the weights: every episode runs the full horizon)."""
    agent = trainer.Agent(cfg, env)
    keys = jax.random.split(jax.random.key(2), cfg.num_seeds)
    return best_seconds(trainer.jit_evaluate(agent), (agent.init_seeds(), keys), repeats)


def profile_table(rows: list[dict]) -> str:
    """A Markdown table: ms per iteration of each part (and its share of the whole)."""
    names = list(rows[0]["parts"])
    head = (
        "| env | E / M / C / eval every | " + " | ".join(names) + " | other | iteration "
        "| evaluation per iteration | env steps/s |"
    )
    lines = [head, "|" + "---|" * (len(names) + 6)]
    for row in rows:
        whole, sched = row["whole"], row["schedule"]
        cells = [
            f"{1e3 * row['parts'][n]:.0f} ms ({100 * row['parts'][n] / whole:.0f}%)" for n in names
        ]
        lines.append(
            f"| {row['env']} | {sched.env_steps} / {sched.sac_updates} / "
            f"{sched.classifier_updates} / {sched.eval_every} | " + " | ".join(cells) + " | "
            f"{1e3 * row['other']:.0f} ms | {whole:.2f} s | "
            f"{1e3 * row['evaluation']:.0f} ms ({100 * row['evaluation'] / whole:.0f}%) | "
            f"{row['env_steps_per_s']:.0f} |"
        )
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--envs", nargs="+", default=list(envs.ENV_NAMES))
    parser.add_argument("--preset", default="quick")
    args = parser.parse_args(argv)
    rows = []
    for name in args.envs:
        rows.append(profile_row(name, args.preset))
        print(profile_table(rows[-1:]).splitlines()[-1], flush=True)
    print(f"\n{jax.devices()[0].device_kind}, preset {args.preset}")
    print(profile_table(rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
