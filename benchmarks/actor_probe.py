"""What a run's deterministic actor does for chosen goals: does it move, or hold one action?

    python -m benchmarks.actor_probe RUN_DIR [--episodes 8] [--seed-index 0] \
        -- "X,Y[,Z];X,Y[,Z]..."

    python -m benchmarks.actor_probe RUN_DIR --route [--episodes 8] -- "X,Y;X,Y..."

(the `--` lets the points start with a minus sign).

Per goal, over N deterministic episodes from the start state with its reset noise (SPEC
§7's evaluation episodes, no goal switching), one row:
  reach       share of the episodes that come within the success radius of the goal;
  steps       env steps to the first success, mean over the episodes that reach it (nan
              if none does): with the path, how fast the policy walks;
  path        length of phi's path over the episode (mean);
  saturated   share of action components with |a| > 0.95;
  std/t       each action component's standard deviation over the episode, averaged: near
              0 when the actor holds one action for the whole episode;
  |u| s_0     largest and mean |u| of the actor's pre-tanh mean at the first state.
An ant that stands still for a goal holds nearly one action (std/t near 0); where that
action is saturated, tanh leaves neither the critic's gradient nor the exploration noise
any hold on it (benchmarks/RESULTS.md, stop 62).

With `--route` the points are waypoints of one route instead: each episode starts with the
first as its goal and switches to the next one when it reaches it (the last stays). Per
waypoint: the share of episodes that got there, and the mean env step of the arrival,
counted from the episode's start. It tells whether the actor's walk along cells it can
reach is fast enough for a goal farther away, apart from whether it goes for that goal.
A diagnostic only: no run ever gives its agent waypoints.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from envs import goal_distance

SATURATED = 0.95
"""|a| above which an action component counts as saturated (tanh(1.83))."""


class ActionStats(NamedTuple):
    """Of one goal's episodes: shares and means over episodes, steps and components."""

    saturated: float
    std_over_time: float


def action_stats(actions: np.ndarray) -> ActionStats:
    """(n, T, |A|) actions of n episodes -> the share of components with |a| > SATURATED,
    and each component's standard deviation over the T steps, averaged over n and |A|."""
    actions = np.asarray(actions, np.float64)
    return ActionStats(
        saturated=float(np.mean(np.abs(actions) > SATURATED)),
        std_over_time=float(np.mean(actions.std(axis=1))),
    )


def arrival(success: np.ndarray) -> tuple[float, float]:
    """(n, T) bool success after each step of n episodes -> (the share of episodes with
    any success, the mean 1-based step of the first one over those episodes, nan if none)."""
    hit = success.any(axis=1)
    first_step = np.argmax(success, axis=1) + 1
    return float(hit.mean()), float(first_step[hit].mean()) if hit.any() else np.nan


class GoalRow(NamedTuple):
    goal: np.ndarray  # (goal_dim,)
    reach: float
    steps: float
    """Env steps to the first success (1-based), mean over the reaching episodes; nan if none."""
    path: float
    stats: ActionStats
    u_max: float
    u_mean: float


def probe(
    env,
    policy,
    pre_tanh_mean: Callable[[jax.Array, jax.Array], jax.Array],
    goals: np.ndarray,
    episodes: int,
    key,
) -> list[GoalRow]:
    """One `GoalRow` per goal of `goals` (n, goal_dim).

    Args:
      env: the environment; policy: a `rollout.Policy` (pass the deterministic actor).
      pre_tanh_mean: (obs (obs_dim,), goal (goal_dim,)) -> the actor's u (|A|,).
      episodes: episodes per goal; key: PRNG key (reset noise).
    """
    from d2c_jax.core import rollout

    goals = np.asarray(goals, np.float32)
    repeated = np.repeat(goals, episodes, axis=0)

    def play(g, k):
        record = lambda before, action, after: (action, after.success, after.achieved_goal)  # noqa: E731
        first, (action, success, achieved) = rollout.run(env, policy, g, k, record=record)
        path = jnp.concatenate([first.achieved_goal[:, None], achieved], axis=1)
        length = jnp.linalg.norm(jnp.diff(path, axis=1), axis=-1).sum(axis=1)
        u = jax.vmap(pre_tanh_mean)(first.obs, g)
        return action, success, length, u

    action, success, length, u = (np.asarray(x) for x in jax.jit(play)(repeated, key))
    rows = []
    for i, goal in enumerate(goals):
        mine = slice(i * episodes, (i + 1) * episodes)
        reach, steps = arrival(success[mine])
        rows.append(
            GoalRow(
                goal=goal,
                reach=reach,
                steps=steps,
                path=float(length[mine].mean()),
                stats=action_stats(action[mine]),
                u_max=float(np.abs(u[mine]).max()),
                u_mean=float(np.abs(u[mine]).mean()),
            )
        )
    return rows


class RouteRow(NamedTuple):
    waypoint: np.ndarray  # (goal_dim,)
    reach: float
    """Share of the episodes that reached this waypoint (so every one before it too)."""
    step: float
    """Env step of the first arrival (1-based, from the episode's start), mean over the
    episodes that arrive; nan if none does."""


def check_route(route: np.ndarray, radius: float) -> None:
    """Raise ValueError unless every two waypoints of `route` (n, goal_dim) lie more than
    2 `radius` apart, so that the waypoint an agent has just reached is the one nearest
    to it (what `route_switch` relies on)."""
    gaps = np.linalg.norm(route[:, None] - route[None], axis=-1)
    gaps[np.diag_indices(len(route))] = np.inf
    i, j = np.unravel_index(np.argmin(gaps), gaps.shape)
    if len(route) > 1 and gaps[i, j] <= 2 * radius:
        raise ValueError(
            f"route waypoints must lie more than 2 success radii ({2 * radius:g}) apart; "
            f"waypoints {i} and {j} are {gaps[i, j]:.3g} apart"
        )


def route_switch(route: jax.Array):
    """A `rollout.GoalSwitch` that follows `route` (n, goal_dim): the waypoint after the
    one nearest the achieved goal, the last one staying. Called on success, the nearest is
    the waypoint just reached (`check_route`)."""

    def next_goal(achieved_goal: jax.Array, key: jax.Array) -> jax.Array:
        nearest = jnp.argmin(goal_distance(route, achieved_goal))
        return route[jnp.minimum(nearest + 1, route.shape[0] - 1)]

    return next_goal


def probe_route(env, policy, route: np.ndarray, episodes: int, key) -> list[RouteRow]:
    """One `RouteRow` per waypoint of `route` (n, goal_dim), over `episodes` episodes that
    start with the first waypoint as their goal (checked with `check_route`).

    Args:
      env: the environment; policy: a `rollout.Policy` (pass the deterministic actor).
      key: PRNG key (reset noise).
    """
    from d2c_jax.core import rollout

    route = np.asarray(route, np.float32)
    check_route(route, env.success_radius)
    switch = route_switch(jnp.asarray(route))

    def play(start, k):
        record = lambda before, action, after: (after.goal, after.success)  # noqa: E731
        _, records = rollout.run(env, policy, start, k, record=record, next_goal=switch)
        return records

    start = np.repeat(route[:1], episodes, axis=0)
    goal, success = (np.asarray(x) for x in jax.jit(play)(start, key))  # (n, T, d), (n, T)
    # The waypoint each step pursued: the goals are the route's points themselves.
    pursued = np.argmin(np.linalg.norm(goal[:, :, None] - route[None, None], axis=-1), axis=-1)
    rows = []
    for i, waypoint in enumerate(route):
        reach, step = arrival(success & (pursued == i))
        rows.append(RouteRow(waypoint=waypoint, reach=reach, step=step))
    return rows


def format_route_rows(rows: list[RouteRow]) -> list[str]:
    """A header and one line per waypoint."""
    lines = ["waypoint              reach  arrival step"]
    for r in rows:
        point = ",".join(f"{v:g}" for v in r.waypoint)
        lines.append(f"{point:20s}  {r.reach:5.2f}  {r.step:12.0f}")
    return lines


def format_rows(rows: list[GoalRow]) -> list[str]:
    """A header and one line per goal."""
    lines = ["goal                  reach  steps   path  saturated  std/t  |u| s_0 max / mean"]
    for r in rows:
        goal = ",".join(f"{v:g}" for v in r.goal)
        lines.append(
            f"{goal:20s}  {r.reach:5.2f}  {r.steps:5.0f}  {r.path:5.2f}  {r.stats.saturated:9.2f}"
            f"  {r.stats.std_over_time:5.2f}  {r.u_max:6.2f} / {r.u_mean:.2f}"
        )
    return lines


def main(argv=None) -> int:
    from benchmarks import goal_probe, run_args
    from d2c_jax.core import networks, sac
    from d2c_jax.training import runs

    parser = run_args.probe_parser(__doc__, episodes=8)
    parser.add_argument("goals", help='goal points as "x,y;x,y" (the env\'s goal space)')
    parser.add_argument(
        "--route", action="store_true", help="the points are waypoints of one route, in order"
    )
    args = parser.parse_args(argv)
    try:
        run_args.check_episodes(args.episodes)
        try:
            goals = goal_probe.parse_points(args.goals)
        except ValueError as err:
            raise runs.RunError(str(err), 2) from None
        cfg, env, ts = runs.load_one_run(args.run, args.seed_index)
        if goals.shape[1] != env.goal_dim:
            raise runs.RunError(
                f"goal points must have {env.goal_dim} coordinates for {cfg.env}, "
                f"got {goals.shape[1]}",
                2,
            )
        if args.route:
            try:
                check_route(goals, env.success_radius)
            except ValueError as err:
                raise runs.RunError(str(err), 2) from None
    except runs.RunError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    nets = networks.make_networks(cfg.sac, env)

    def pre_tanh_mean(obs, goal):
        feats = networks.actor_input(env, obs, goal, nets.relative_goal)
        return nets.actor.apply(ts.sac.actor_params, feats)[0]

    policy = sac.make_policy(nets, ts.sac, env, deterministic=True)
    if args.route:
        rows = probe_route(env, policy, goals, args.episodes, jax.random.key(1))
        print(f"{args.run}: {int(ts.env_steps):,} env steps, {args.episodes} episodes, one route")
        print("\n".join(format_route_rows(rows)))
        return 0
    rows = probe(env, policy, pre_tanh_mean, goals, args.episodes, jax.random.key(1))
    print(f"{args.run}: {int(ts.env_steps):,} env steps, {args.episodes} episodes per goal")
    print("\n".join(format_rows(rows)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
