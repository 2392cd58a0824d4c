"""Is a trained run's critic inside SPEC §4's sanity bound where the agent has not been?

    python -m benchmarks.critic_probe RUN_DIR [--step N] [--episodes 200] [--seed-index 0]

`sac/q_mean` averages the critic over replayed batches, whose goals are mostly relabelled
ones the agent reached (HER), so a critic far below the return's range on the goals it has
not reached keeps a healthy mean. This probe reads the run's checkpoint and prints:

- the floor of the soft return: with rewards >= 0 and the entropy at its target H*, a soft
  Q-value is at least gamma * alpha * H* / (1 - gamma) (Eq. 3 with r = 0 forever);
- V(s_0, g) = min_i Q_i(s_0, pi(s_0, g), g) at each desired outcome g, over the start
  states of the newest `episodes` episodes;
- over the stored (s_t, g_t) pairs of the newest `episodes` episodes: V's mean, 1st
  percentile and the share below the floor;
- the share of episodes whose achieved goal never leaves the success radius around
  phi(s_0) (an ant that stays at the start, a peg never pushed), in the buffer's time order;
- the share of HER's "future" goals (t' uniform in [t + 1, H]) already within the success
  radius of phi(s_t), over the whole buffer: goals reached before acting, which teach
  nothing about reaching (`her.min_future_radii` leaves them out).

A critic below the floor is pessimistic beyond what any behaviour can earn (SPEC §4's
sanity bound), which `sac/q_mean` hides; measured on the Ant and Sawyer runs and not on
`medium_maze` (benchmarks/RESULTS.md, "Why the ant stays at the start, and the critic
below the return's floor").
"""

from __future__ import annotations

import sys

import jax
import jax.numpy as jnp
import numpy as np

from benchmarks import run_args
from d2c_jax.core import replay, rollout, sac
from d2c_jax.training import agent as agent_lib
from d2c_jax.training import runs

BLOCKS = 8
"""Blocks of the buffer, oldest to newest, for the still share."""


def already_reached_share(
    achieved_goal: np.ndarray, radius: float, draws: int = 100_000, seed: int = 0
) -> float:
    """Share of HER "future" goals phi(s_t'), t uniform in [0, H) and t' in [t + 1, H] of a
    uniformly drawn episode, within `radius` of phi(s_t) (a Monte-Carlo estimate).

    Args:
      achieved_goal: (E, H + 1, goal_dim) phi(s_t) of E episodes.
    """
    rng = np.random.default_rng(seed)
    horizon = achieved_goal.shape[1] - 1
    episode = rng.integers(0, achieved_goal.shape[0], draws)
    step = rng.integers(0, horizon, draws)
    future = rng.integers(step + 1, horizon + 1)
    gap = achieved_goal[episode, future] - achieved_goal[episode, step]
    return float(np.mean(np.linalg.norm(gap, axis=-1) <= radius))


def report(cfg, env, ts, episodes: int) -> list[str]:
    """The probe's lines for one run's TrainState `ts` (no run axis)."""
    agent = agent_lib.Agent(cfg, env)
    value = jax.jit(lambda o, g: sac.state_value(agent.sac_nets, ts.sac, env, o, g))
    rp = jax.tree.map(np.asarray, ts.replay)
    newest_first, _ = replay.recent_episode_slots(ts.replay, int(rp.size))
    order = np.asarray(newest_first)[::-1]  # the stored episodes, oldest first
    newest = order[-episodes:]
    alpha = float(jnp.exp(ts.sac.log_alpha))
    floor = sac.soft_return_floor(alpha, sac.target_entropy(cfg.sac, env.action_dim), cfg.sac.gamma)
    lines = [
        f"alpha {alpha:.4f}; floor of the soft return {floor:.1f}, its ceiling about "
        f"{1.0 / (1.0 - cfg.sac.gamma):.0f}"
    ]
    starts = rp.obs[newest, 0]
    for k, point in enumerate(np.asarray(env.goal_points, np.float32)):
        v = np.asarray(value(starts, np.broadcast_to(point, (len(newest), point.shape[0]))))
        lines.append(f"V(s_0, mode {k}): mean {v.mean():.1f}, min {v.min():.1f}, max {v.max():.1f}")
    obs = rp.obs[newest, :-1].reshape(-1, rp.obs.shape[-1])
    goals = rp.goal[newest].reshape(-1, rp.goal.shape[-1])
    v = np.asarray(value(obs, goals))
    lines.append(
        f"V(s_t, g_t) over the newest {len(newest)} episodes: mean {v.mean():.1f}, "
        f"1st percentile {np.percentile(v, 1):.1f}, below the floor {np.mean(v < floor):.2f}"
    )
    still = np.asarray(rollout.stayed_at_start(rp.achieved_goal[order], env.success_radius))
    horizon = rp.action.shape[1]
    step_now = int(ts.env_steps)
    shares = []
    for block in np.array_split(np.arange(len(order)), BLOCKS):
        if len(block):
            at = step_now - (len(order) - block[-1] - 1) * horizon
            shares.append(f"{at / 1e3:.0f}k {still[block].mean():.2f}")
    lines.append(
        "episodes whose phi never leaves the success radius, by buffer block "
        "(env steps at its end): " + ", ".join(shares)
    )
    reached = already_reached_share(rp.achieved_goal[order], env.success_radius)
    lines.append(f"HER future goals already within the success radius of phi(s_t): {reached:.2f}")
    return lines


def main(argv=None) -> int:
    parser = run_args.probe_parser(__doc__, episodes=200)
    parser.add_argument("--step", type=int, default=None, help="checkpoint iteration")
    args = parser.parse_args(argv)
    try:
        run_args.check_episodes(args.episodes)
        cfg, env, ts = runs.load_one_run(args.run, args.seed_index, args.step)
    except runs.RunError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    print(f"{args.run}: {int(ts.env_steps):,} env steps")
    for line in report(cfg, env, ts, args.episodes):
        print(line)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
