"""How D2C's reward p_pseudo(x; g) falls off with the distance from the goal, for a trained run.

    python -m benchmarks.reward_probe RUN_DIR [--points 4000] [--seed-index 0]

For `points` visited achieved goals g (uniform over the run's replay buffer) it prints
the mean p_pseudo(x; g) for x = g + a random direction times 0, 0.5, 1, 2, 4 and 8
success radii (clipped to the goal bounds), and for x = another visited state, grouped by
its distance from g. A reward that pays for hovering near the goal shows as a high p at
1-2 radii; an object that seldom moves shows as most visited pairs within one radius.
"""

from __future__ import annotations

import sys

import jax
import jax.numpy as jnp

import envs
from benchmarks import run_args
from d2c_jax.core import replay
from d2c_jax.curricula import classifier
from d2c_jax.training import runs

RADII = (0.0, 0.5, 1.0, 2.0, 4.0, 8.0)
BANDS = ((0, 1), (1, 2), (2, 4), (4, 8), (8, float("inf")))


def probe(cfg, env, ts, points: int, key) -> list[str]:
    """The report's lines for one run's TrainState `ts` (no run axis)."""
    net = classifier.make_classifier(cfg.classifier, env)
    k_goals, k_others, k_dirs = jax.random.split(key, 3)
    goals = replay.sample_achieved_goals(ts.replay, points, k_goals)  # (n, d)
    others = replay.sample_achieved_goals(ts.replay, points, k_others)  # (n, d)
    radius = env.success_radius
    direction = jax.random.normal(k_dirs, goals.shape) * jnp.asarray(env.goal_noise_mask)
    direction = direction / jnp.linalg.norm(direction, axis=-1, keepdims=True)
    lines = [f"success radius {radius}, positive noise eps {cfg.classifier.eps}"]
    for m in RADII:
        x = env.clip_goal(goals + m * radius * direction)
        p = classifier.p_pseudo(net, ts.classifier.params, x, goals)
        lines.append(f"x = g + {m:3.1f} radii: mean p {float(p.mean()):.3f}")
    dist = envs.goal_distance(others, goals)
    p = classifier.p_pseudo(net, ts.classifier.params, others, goals)
    for lo, hi in BANDS:
        mask = (dist >= lo * radius) & (dist < hi * radius)
        n = int(mask.sum())
        mean = f"{float(jnp.where(mask, p, 0).sum() / n):.3f}" if n else "-"
        lines.append(f"another visited x, {lo}-{hi} radii from g: {n} pairs, mean p {mean}")
    return lines


def main(argv=None) -> int:
    parser = run_args.probe_parser(__doc__)
    parser.add_argument("--points", type=int, default=4000)
    args = parser.parse_args(argv)
    try:
        cfg, env, ts = runs.load_one_run(args.run, args.seed_index)
    except runs.RunError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    print("\n".join(probe(cfg, env, ts, args.points, jax.random.key(0))))
    return 0


if __name__ == "__main__":
    sys.exit(main())
