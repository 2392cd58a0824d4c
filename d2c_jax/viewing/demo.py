"""Demo: random-policy rollouts in each maze, drawn over the maze.

    python -m d2c_jax.demo --out runs/demo

Writes `<out>/random_rollouts.png`. Useful to check an install: it builds every maze,
jits the episode loop (`rollout.trajectories`, a scan over a step vmapped over episodes)
with a random policy and draws the paths.
"""

from __future__ import annotations

import argparse
import pathlib
import sys

import jax
import jax.numpy as jnp

import envs
from d2c_jax.core import rollout
from d2c_jax.viewing import plots

MAZES = ("complex_maze", "medium_maze", "spiral_maze")


def random_rollouts(env, key: jax.Array, n_episodes: int) -> jax.Array:
    """Achieved-goal trajectories (n_episodes, H + 1, goal_dim) of a uniform random policy.

    The episode loop (`rollout.trajectories`) with `rollout.random_policy`; episode i is
    conditioned on goal mode i mod n_modes (instead of `env.reset`'s random mode: the
    random policy ignores its goal, and cycling covers every mode).
    """
    modes = jnp.asarray(env.goal_points)
    goals = modes[jnp.arange(n_episodes) % modes.shape[0]]  # (n_episodes, goal_dim)
    policy = rollout.random_policy(env.action_dim)
    episodes = jax.jit(lambda goals, k: rollout.trajectories(env, policy, goals, k))
    return episodes(goals, key).achieved_goal


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="runs/demo", help="output directory")
    parser.add_argument("--episodes", type=int, default=32, help="episodes per maze")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    if args.episodes <= 0:
        print(f"error: --episodes must be positive, got {args.episodes}", file=sys.stderr)
        return 2
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    mazes = [envs.make(name) for name in MAZES]
    fig, axes = plots.map_figure([(env, name) for env, name in zip(mazes, MAZES, strict=True)])
    for i, (env, ax) in enumerate(zip(mazes, axes, strict=True)):
        trajs = random_rollouts(env, jax.random.key(args.seed + i), args.episodes)
        plots.draw_trajectories(ax, trajs)
    path = out / "random_rollouts.png"
    plots.save(fig, path)
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
