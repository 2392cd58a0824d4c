"""D2C training: `TrainState`, the one jitted iteration, and the `train()` host loop.

One iteration (SPEC §2, paper Alg. 1 made parallel) is one compiled program:
  1. curriculum goals by matching (Eq. 6-7),
  2. collect num_envs episodes (vmap over envs, scan over H),
  3. store them,
  4. M SAC updates on HER batches with the intrinsic reward, interleaved evenly with
     the classifier updates (Eq. 5).
The schedules are static: the host decides which iterations are warm-up (random
actions) and passes one flag shared by all seeds, never a per-seed `lax.cond`, so
vmapped seeds pay for nothing twice.
"""

from __future__ import annotations

import math
import pathlib
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

import envs
from d2c_jax import config as config_lib
from d2c_jax.core import her, networks, replay, rollout, sac
from d2c_jax.curricula import classifier, curriculum
from d2c_jax.training.loop import RunError  # noqa: F401  (re-exported for the CLI)


class Schedule(NamedTuple):
    """Static per-iteration counts derived from the config and the env (SPEC §2)."""

    env_steps: int  # E = num_envs * H
    sac_updates: int  # M = round(E * utd), rounded to whole update blocks
    classifier_updates: int  # round(f_iters * E / f_update_every)
    warmup_iterations: int  # ceil(seed_steps / E)
    eval_every: int  # iterations between evaluations
    total_iterations: int  # ceil(total_steps / E)
    rematch_every: int  # iterations between curriculum matchings


def make_schedule(cfg: config_lib.TrainConfig, horizon: int) -> Schedule:
    """The static schedule of SPEC §2 for `cfg` and an env of this horizon."""
    e = cfg.num_envs * horizon
    block = sac.block_size(cfg.sac)  # updates come in whole blocks (no cond, see sac_block)
    return Schedule(
        env_steps=e,
        sac_updates=block * max(1, round(e * cfg.utd / block)),
        classifier_updates=round(cfg.classifier.iters * e / cfg.classifier.update_every),
        warmup_iterations=math.ceil(cfg.seed_steps / e),
        eval_every=max(1, math.ceil(cfg.eval_every / e)),
        total_iterations=math.ceil(cfg.total_steps / e),
        rematch_every=max(1, round(cfg.curriculum.rematch_every / e)),
    )


@struct.dataclass
class TrainState:
    """Everything one seed's training evolves (leading seed axis when vmapped).

    Episodes restart from reset every iteration (SPEC §2: whole episodes per
    iteration), so no env state persists between iterations; the curriculum pool is the
    replay buffer's most recent episodes.
    """

    sac: sac.SACState
    classifier: classifier.ClassifierState
    replay: replay.ReplayState
    desired: jax.Array  # (n_modes, examples_per_mode, goal_dim) desired examples, SPEC §1
    curriculum_goals: jax.Array  # (n_slots, goal_dim) the goals of the last matching
    matching_metrics: dict  # () float32 each: "curriculum/*" metrics of the last matching
    key: jax.Array  # () PRNG key
    iteration: jax.Array  # () int32 iterations done
    env_steps: jax.Array  # () int32 env steps done


class HostConstants(NamedTuple):
    """Env facts the step needs, computed once on the host (never inside the trace)."""

    start_goal: np.ndarray  # (goal_dim,) phi of the start state, the warm-up centre
    start_obs: np.ndarray | None  # (obs_dim,) a start observation, only for "+Value" V(s0, g)


def host_constants(cfg: config_lib.TrainConfig, env: envs.GoalEnv) -> HostConstants:
    """Reads the start state on the host: `env.start_goal` may reset the env and convert
    the result to numpy, which a traced step cannot do (it crashed Sawyer before). The
    start observation costs a compiled reset, so only the "+Value" ablation gets one."""
    start_obs = None
    if cfg.curriculum.variant == "value":
        zero_goal = np.zeros(env.goal_dim, np.float32)
        start = jax.jit(env.reset_with_goal)(jax.random.key(0), zero_goal)
        start_obs = np.asarray(start.obs, np.float32)
    return HostConstants(start_goal=np.asarray(env.start_goal, np.float32), start_obs=start_obs)


class Components(NamedTuple):
    """The static pieces one iteration is built from (modules and constants, not state)."""

    env: envs.GoalEnv
    sac_nets: networks.SACNetworks
    classifier_net: classifier.Classifier
    schedule: Schedule
    constants: HostConstants


def make_components(cfg: config_lib.TrainConfig, env: envs.GoalEnv) -> Components:
    """Networks, schedule and host constants for `cfg` on `env` (call it on the host)."""
    return Components(
        env=env,
        sac_nets=networks.make_networks(cfg.sac, env),
        classifier_net=classifier.make_classifier(cfg.classifier, env),
        schedule=make_schedule(cfg, env.horizon),
        constants=host_constants(cfg, env),
    )


def init_train_state(cfg: config_lib.TrainConfig, comp: Components, key: jax.Array) -> TrainState:
    """A fresh TrainState for one seed (vmap it over seed keys for a sweep)."""
    env = comp.env
    key, k_sac, k_clf, k_des = jax.random.split(key, 4)
    return TrainState(
        sac=sac.init_sac(cfg.sac, comp.sac_nets, env, k_sac),
        classifier=classifier.init_classifier(
            cfg.classifier, comp.classifier_net, env.goal_dim, k_clf
        ),
        replay=replay.init_replay(
            cfg.replay, env.obs_dim, env.action_dim, env.goal_dim, env.horizon
        ),
        desired=curriculum.desired_examples(env, cfg.curriculum.examples_per_mode, k_des),
        curriculum_goals=jnp.zeros((cfg.curriculum.n_slots, env.goal_dim), jnp.float32),
        matching_metrics={k: jnp.zeros((), jnp.float32) for k in curriculum.METRIC_KEYS},
        key=key,
        iteration=jnp.zeros((), jnp.int32),
        env_steps=jnp.zeros((), jnp.int32),
    )


def init_seed_states(cfg: config_lib.TrainConfig, comp: Components) -> TrainState:
    """TrainStates of seeds S..S+N-1, stacked on a leading (num_seeds,) axis (jitted)."""
    return jax.jit(jax.vmap(lambda k: init_train_state(cfg, comp, k)))(seed_keys(cfg))


def seed_keys(cfg: config_lib.TrainConfig) -> jax.Array:
    """(num_seeds,) keys of seeds S..S+N-1: seed s of a sweep = a single run with seed s."""
    return jnp.stack([jax.random.key(cfg.seed + i) for i in range(cfg.num_seeds)])


# --- one iteration ----------------------------------------------------------------------


def _reward_fn(cfg, comp: Components, clf_params):
    """The reward of SPEC §4: intrinsic p_pseudo, or the sparse ablation."""
    if cfg.reward == "sparse":
        return her.sparse_reward_fn(comp.env)
    return classifier.make_reward_fn(comp.classifier_net, clf_params)


def _value_fn(cfg, comp: Components, ts: TrainState):
    """V(s0, g) = min_i Q_i(s0, pi(s0, g), g) for the "+Value" ablation (appendix C.2)."""
    if cfg.curriculum.variant != "value":
        return None
    s0 = jnp.asarray(comp.constants.start_obs)

    def value_fn(goals):
        return sac.state_value(comp.sac_nets, ts.sac, comp.env, s0, goals)

    return value_fn


def sac_block(cfg, comp: Components, ts: TrainState, key) -> tuple[TrainState, dict]:
    """`sac.block_size` SAC updates (critic each, actor and target on their cadences).

    Each update gets its own HER batch, with rewards from the current classifier. A
    statically unrolled block needs no `lax.cond` on the update counter, which under vmap
    (seeds) would compute the actor update at every step.
    """
    k_batch, k_upd = jax.random.split(key)
    reward_fn = _reward_fn(cfg, comp, ts.classifier.params)
    keys = jax.random.split(k_batch, sac.block_size(cfg.sac))
    walk = cfg.replay.walk_fraction
    batches = jax.vmap(
        lambda k: her.relabel(cfg.her, ts.replay, cfg.sac.batch_size, reward_fn, k, walk)
    )(keys)
    new_sac, metrics = sac.update_sac_block(
        cfg.sac, comp.sac_nets, ts.sac, batches, comp.env, k_upd
    )
    return ts.replace(sac=new_sac), metrics


def classifier_update(cfg, comp: Components, ts: TrainState, key) -> tuple[TrainState, dict]:
    """One Eq. 5 update: negatives are achieved goals of random buffer states (of the
    curriculum phase only, with `negatives="curriculum_phase"`)."""
    k_states, k_batch = jax.random.split(key)
    states = replay.sample_achieved_goals(
        ts.replay,
        cfg.classifier.batch_size,
        k_states,
        curriculum_phase_only=cfg.classifier.negatives == "curriculum_phase",
    )
    batch = classifier.sample_batch(cfg.classifier, comp.env, states, ts.desired, k_batch)
    new_clf, metrics = classifier.update_classifier(
        cfg.classifier, comp.classifier_net, ts.classifier, batch
    )
    return ts.replace(classifier=new_clf), metrics


def scan_updates(update, ts: TrainState, n: int, key):
    """`n` applications of update(ts, key) -> (ts, metrics) by lax.scan; mean metrics."""
    if n == 0:
        return ts, {}

    def body(ts, k):
        return update(ts, k)

    ts, metrics = jax.lax.scan(body, ts, jax.random.split(key, n))
    return ts, jax.tree.map(jnp.mean, metrics)


def _updates(cfg, comp: Components, ts: TrainState, key) -> tuple[TrainState, dict]:
    """M SAC updates interleaved evenly with C classifier updates (SPEC §2 step 4).

    With n = M / block_size SAC blocks: C rounds of (1 classifier update, n // C SAC
    blocks), then the n mod C remaining blocks; all counts are static.
    """
    n = comp.schedule.sac_updates // sac.block_size(cfg.sac)
    c = comp.schedule.classifier_updates
    sac_step = lambda ts, k: sac_block(cfg, comp, ts, k)  # noqa: E731
    clf_step = lambda ts, k: classifier_update(cfg, comp, ts, k)  # noqa: E731
    k_rounds, k_rest = jax.random.split(key)
    if c == 0:
        return scan_updates(sac_step, ts, n, k_rounds)

    def one_round(ts, k):
        k_clf, k_sac = jax.random.split(k)
        ts, clf_metrics = clf_step(ts, k_clf)
        ts, sac_metrics = scan_updates(sac_step, ts, n // c, k_sac)
        return ts, {**clf_metrics, **sac_metrics}

    ts, metrics = jax.lax.scan(one_round, ts, jax.random.split(k_rounds, c))
    ts, rest = scan_updates(sac_step, ts, n % c, k_rest)
    # SAC metrics: the rounds' mean where rounds hold SAC updates, else the remainder's.
    return ts, {**rest, **jax.tree.map(jnp.mean, metrics)}


def collect_episodes(cfg, comp: Components, ts: TrainState, goals, warmup, key):
    """Episodes of this iteration: random actions while `warmup` (a () bool), else the actor.

    The warm-up flag is a traced scalar shared by all seeds, so warm-up and training
    iterations are one compiled program; a `jnp.where` picks the action (the actor's
    forward pass is cheap next to the updates).
    """
    env = comp.env
    actor = sac.make_policy(comp.sac_nets, ts.sac, env, deterministic=False)
    uniform = rollout.random_policy(env.action_dim)

    def policy(obs, goal, key):
        k_actor, k_uniform = jax.random.split(key)
        return jnp.where(warmup, uniform(obs, goal, k_uniform), actor(obs, goal, k_actor))

    def next_goal(ag, k):
        return curriculum.post_success_goal(
            cfg.curriculum, env, comp.classifier_net, ts.classifier.params, ag, k
        )

    switch_every = cfg.curriculum.post_success_switch_every
    return rollout.collect(env, policy, next_goal, goals, cfg.num_envs, key, switch_every)


def _matching_pool(cfg, ts: TrainState, key) -> tuple[jax.Array, jax.Array]:
    """The curriculum's pool: the P most recent episodes, then `archive_size` episodes
    drawn from the whole buffer (issue 10 rule 5).

    Archive rows beyond the episodes stored so far repeat the most recent episode, so the
    pool counts as full (the warm-up ends) as soon as P episodes exist.

    Returns:
      buffer slots (P + A,) int32 and valid (P + A,) bool.
    """
    slots, valid = replay.recent_episode_slots(ts.replay, cfg.curriculum.pool_size)
    if cfg.curriculum.archive_size == 0:
        return slots, valid
    archived, archived_valid = replay.archived_episode_slots(
        ts.replay, cfg.curriculum.archive_size, key
    )
    archived = jnp.where(archived_valid, archived, slots[0])
    return (
        jnp.concatenate([slots, archived]),
        jnp.concatenate([valid, jnp.broadcast_to(valid[0], archived_valid.shape)]),
    )


def _goal_value_fn(cfg, comp: Components, ts: TrainState):
    """V(s, g) = min_i Q_i(s, pi(s, g), g) over pool observations (P, T', o) and one goal
    (d,), for `curriculum.goal_value_weight`; None when that is 0."""
    if cfg.curriculum.goal_value_weight == 0:
        return None

    def goal_value_fn(obs, goal):
        goals = jnp.broadcast_to(goal, obs.shape[:-1] + goal.shape)
        return sac.state_value(comp.sac_nets, ts.sac, comp.env, obs, goals)

    return goal_value_fn


def params_finite(ts: TrainState) -> jax.Array:
    """() bool: every SAC and classifier parameter is finite."""
    leaves = jax.tree.leaves((ts.sac, ts.classifier.params))
    floats = [jnp.all(jnp.isfinite(x)) for x in leaves if jnp.issubdtype(x.dtype, jnp.floating)]
    return jnp.all(jnp.stack(floats))


def curriculum_goals(cfg, comp: Components, ts: TrainState, key) -> tuple[jax.Array, dict]:
    """Goals (K, d) of this iteration: a new matching every `schedule.rematch_every`
    iterations, else the held goals (their `curriculum/*` metrics with them).

    `lax.cond` on the iteration count: a real branch for one seed; under vmap over seeds
    it becomes a select and matches every iteration, as before.
    """

    def match():
        slots, pool_valid = _matching_pool(cfg, ts, jax.random.fold_in(key, 1))
        goal_value_fn = _goal_value_fn(cfg, comp, ts)
        pool_ag = ts.replay.achieved_goal[slots]  # (P + A, H + 1, d)
        pool_obs = None if goal_value_fn is None else ts.replay.obs[slots]
        goals, metrics = curriculum.propose(
            cfg.curriculum,
            comp.env,
            comp.classifier_net,
            ts.classifier.params,
            pool_ag,
            pool_valid,
            jnp.asarray(comp.constants.start_goal),
            key,
            _value_fn(cfg, comp, ts),
            cfg.sac.gamma,
            eps=cfg.classifier.eps,
            pool_obs=pool_obs,
            goal_value_fn=goal_value_fn,
        )
        return goals, jax.tree.map(lambda x: x.astype(jnp.float32), metrics)

    if comp.schedule.rematch_every == 1:
        return match()
    due = ts.iteration % comp.schedule.rematch_every == 0
    return jax.lax.cond(due, match, lambda: (ts.curriculum_goals, ts.matching_metrics))


def env_goals(cfg, comp: Components, ts: TrainState, goals: jax.Array) -> jax.Array:
    """(num_envs, d) goals: env i of the r-th iteration since the matching takes slot
    (i + r * num_envs) mod K, so held goals are used in turn rather than the first ones."""
    rounds = ts.iteration % comp.schedule.rematch_every
    slots = (jnp.arange(cfg.num_envs) + rounds * cfg.num_envs) % goals.shape[0]
    return goals[slots]


def train_iteration(cfg, comp: Components, ts: TrainState, warmup: jax.Array):
    """One D2C iteration for one seed: curriculum -> collect -> store -> updates.

    Args:
      warmup: () bool, random actions this iteration (SPEC §2 warm-up).
    """
    env = comp.env
    key, k_cur, k_col, k_upd = jax.random.split(ts.key, 4)
    goals, cur_metrics = curriculum_goals(cfg, comp, ts, k_cur)
    episodes = collect_episodes(cfg, comp, ts, env_goals(cfg, comp, ts, goals), warmup, k_col)
    ts = ts.replace(
        replay=replay.insert_episodes(ts.replay, episodes),
        curriculum_goals=goals,
        matching_metrics=cur_metrics,
        key=key,
        iteration=ts.iteration + 1,
        env_steps=ts.env_steps + comp.schedule.env_steps,
    )
    ts, upd_metrics = _updates(cfg, comp, ts, k_upd)
    metrics = {
        **cur_metrics,
        **upd_metrics,
        "train/success_rate": episodes.success.any(axis=1).mean(),
        "train/walk_share": 1.0 - episodes.walk_start.mean() / env.horizon,
        "train/final_distance": envs.goal_distance(
            episodes.achieved_goal[:, -1], episodes.goal[:, -1]
        ).mean(),
        "health/params_finite": params_finite(ts),
    }
    return ts, metrics


def over_seeds(fn, num_seeds: int, in_axes: tuple):
    """`jax.vmap(fn, in_axes)` over the leading seed axis, without a size-1 batch axis.

    With one seed, fn runs on the squeezed arguments and its outputs get the axis back:
    the same function, but XLA's CPU matmuls then carry no size-1 batch dimension, which
    made the 3x512 SAC update 10% slower (measured 18.4 against 20.5 updates/s, 2 cores).
    """
    if num_seeds != 1:
        return jax.vmap(fn, in_axes=in_axes)

    def single(*args):
        squeezed = [
            a if ax is None else jax.tree.map(lambda x: x[0], a)
            for a, ax in zip(args, in_axes, strict=True)
        ]
        return jax.tree.map(lambda x: x[None], fn(*squeezed))

    return single


def make_train_step(cfg: config_lib.TrainConfig, env: envs.GoalEnv):
    """THE jit boundary: one iteration, vmapped over the leading seed axis of TrainState.

    Returns:
      step(ts, warmup) -> (ts, metrics): every leaf of ts and metrics is batched over
      seeds; `warmup` is one () bool for all seeds (the host's static schedule).
    """
    comp = make_components(cfg, env)
    step = lambda ts, warmup: train_iteration(cfg, comp, ts, warmup)  # noqa: E731
    return jax.jit(over_seeds(step, cfg.num_seeds, in_axes=(0, None)), donate_argnums=0)


def make_eval_step(cfg: config_lib.TrainConfig, env: envs.GoalEnv):
    """Jitted SPEC §7 evaluation, vmapped over seeds: (ts, keys) -> metrics."""
    comp = make_components(cfg, env)

    def evaluate(ts: TrainState, key):
        policy = sac.make_policy(comp.sac_nets, ts.sac, env, deterministic=True)
        per_mode = rollout.evaluate(env, policy, cfg.eval_episodes, key)
        metrics = {"eval/success": per_mode.mean()}
        return {**metrics, **{f"eval/success/{k}": per_mode[k] for k in range(env.n_modes)}}

    return jax.jit(over_seeds(evaluate, cfg.num_seeds, in_axes=(0, 0)))


# --- the host loop ----------------------------------------------------------------------


def _eval_keys(cfg: config_lib.TrainConfig, iteration: int) -> jax.Array:
    """Evaluation keys per seed, a pure function of (seed, iteration): resume-safe."""
    return jnp.stack(
        [
            jax.random.fold_in(jax.random.key(cfg.seed + i + 10_000), iteration)
            for i in range(cfg.num_seeds)
        ]
    )


def _is_eval_iteration(iteration: int, sched: Schedule) -> bool:
    """Scheduled evaluations (the final one is added by the loop)."""
    return iteration % sched.eval_every == 0


def _describe(cfg: config_lib.TrainConfig, sched: Schedule) -> str:
    return (
        f"d2c_jax: env {cfg.env}, preset {cfg.preset}, "
        f"seeds {cfg.seed}..{cfg.seed + cfg.num_seeds - 1}"
        f", device {jax.devices()[0].platform}:{jax.devices()[0].device_kind}\n"
        f"  {sched.total_iterations} iterations x {sched.env_steps} env steps, "
        f"{sched.sac_updates} SAC + {sched.classifier_updates} classifier updates each, "
        f"warm-up {sched.warmup_iterations}, eval every {sched.eval_every}"
    )


def _write_plots(out: pathlib.Path, env: envs.GoalEnv) -> None:
    from d2c_jax.training import logging as logging_lib
    from d2c_jax.viewing import plots

    rows = logging_lib.read_metrics(out / "metrics.jsonl")
    plots.success_curve(rows, env.n_modes, out / "plots" / "success.png")
    plots.curriculum_snapshots(rows, env, out / "plots" / "curriculum.png")
    plots.metric_curve(rows, "curriculum/distance", out / "plots" / "curriculum_distance.png")


def train(cfg: config_lib.TrainConfig, out, resume: bool = False, quiet: bool = False) -> int:
    """Runs (or resumes) training into run directory `out`; returns the exit status.

    Raises:
      RunError: bad run directory or checkpoint (status 2), non-finite values (status 3).
    """
    from d2c_jax.training import logging as logging_lib
    from d2c_jax.training import loop as run_loop

    out = pathlib.Path(out)
    env = envs.make(cfg.env)
    sched = make_schedule(cfg, env.horizon)
    run_loop.prepare_run_dir(out, cfg, resume)
    if not quiet:
        print(_describe(cfg, sched), flush=True)
    comp = make_components(cfg, env)
    ts = init_seed_states(cfg, comp)
    ckpt = run_loop.open_checkpointer(out)
    start = 0
    if resume:
        start, ts = run_loop.restore_or_fail(ckpt, ts, out)
        # A run stopped by a signal evaluated at its last iteration; an uninterrupted run
        # evaluates there only on schedule, so drop an unscheduled evaluation.
        strip = () if _is_eval_iteration(start, sched) else ("eval/", "curriculum/goals")
        logging_lib.truncate_metrics(out / "metrics.jsonl", start, strip_last=strip)
    elif (out / "metrics.jsonl").exists():
        (out / "metrics.jsonl").unlink()
    clock = run_loop.Stopwatch()
    # Compile ahead of time, so time/compile_s is separate from the first iteration.
    train_step = make_train_step(cfg, env).lower(ts, jnp.asarray(True)).compile()
    eval_step = make_eval_step(cfg, env).lower(ts, _eval_keys(cfg, 0)).compile()
    timing = {"time/compile_s": clock.lap()}
    writer = logging_lib.MetricsWriter(out / "metrics.jsonl")
    status, shown_success = 0, "-"
    with run_loop.catch_stop_signals() as stop, run_loop.make_progress() as progress:
        task = progress.add_task(
            cfg.env,
            total=sched.total_iterations * sched.env_steps,
            completed=start * sched.env_steps,
            rate=0.0,
            success="-",
            visible=not quiet,
        )
        for it in range(start, sched.total_iterations):
            ts, metrics = train_step(ts, jnp.asarray(it < sched.warmup_iterations))
            row = run_loop.host_metrics(metrics, cfg.num_seeds)
            run_loop.check_finite(row, it + 1)
            last = it + 1 == sched.total_iterations or stop.signal is not None
            if _is_eval_iteration(it + 1, sched) or last:
                row.update(
                    run_loop.host_metrics(eval_step(ts, _eval_keys(cfg, it + 1)), cfg.num_seeds)
                )
                goals = jax.device_get(ts.curriculum_goals)
                row["curriculum/goals"] = goals[0] if cfg.num_seeds == 1 else goals
            lap = clock.lap()
            row = {
                "iteration": it + 1,
                "env_steps": (it + 1) * sched.env_steps,
                **row,
                "time/iteration_s": lap,
                "time/env_steps_per_s": sched.env_steps / lap,
                "time/elapsed_s": clock.elapsed(),
                **timing,
            }
            writer.write(row)
            if timing and not quiet:  # the first iteration of this process
                left = (sched.total_iterations - it - 1) * lap / 60
                progress.console.print(f"  estimated time to finish: {left:.1f} min")
            timing = {}
            if "eval/success" in row:
                shown_success = f"{logging_lib.mean_of(row['eval/success']):.2f}"
            progress.update(
                task,
                completed=(it + 1) * sched.env_steps,
                rate=sched.env_steps / lap,
                success=shown_success,
            )
            if last or (it + 1) % cfg.checkpoint_every == 0:
                ckpt.save(it + 1, ts)
            if stop.signal is not None:
                status = 128 + stop.signal
                break
    writer.close()
    ckpt.close()
    _write_plots(out, env)
    return status
