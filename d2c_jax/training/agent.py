"""The D2C agent: the `Agent` built once per (config, env), and its one jitted iteration.
The state it evolves (`TrainState`, `Schedule`, `Hyperparams`, `HostConstants`) is
defined in `d2c_jax.training.state` and re-exported here.

One iteration (SPEC §2, paper Alg. 1 made parallel) is one compiled program:
  1. curriculum goals by matching (Eq. 6-7),
  2. collect num_envs episodes (vmap over envs, scan over H),
  3. store them,
  4. M SAC updates on HER batches with the intrinsic reward, interleaved evenly with
     the classifier updates (Eq. 5).
The schedules are static (`Schedule`). Warm-up iterations (random actions) are those with
`ts.iteration < warmup_iterations`, a select inside the program rather than a branch, so
vmapped seeds pay for nothing twice. This module holds no host code: the loop that runs,
evaluates, logs and checkpoints is `d2c_jax.training.loop`.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

import envs
from d2c_jax import config as config_lib
from d2c_jax.core import her, networks, replay, rollout, sac
from d2c_jax.core.types import RewardFn
from d2c_jax.curricula import classifier, curriculum, interface
from d2c_jax.training import sac_loop, sweep
from d2c_jax.training.programs import jit_evaluate as jit_evaluate
from d2c_jax.training.programs import jit_step as jit_step
from d2c_jax.training.programs import over_runs as over_runs
from d2c_jax.training.state import HostConstants as HostConstants
from d2c_jax.training.state import Hyperparams as Hyperparams
from d2c_jax.training.state import Schedule as Schedule
from d2c_jax.training.state import TrainState as TrainState
from d2c_jax.training.state import host_constants as host_constants
from d2c_jax.training.state import hyperparams as hyperparams
from d2c_jax.training.state import make_schedule as make_schedule

# Buffer states in the KDE of the archive's rarity weights (`Agent._archive_log_weights`).
_RARITY_POINTS = 1024


class Agent:
    """D2C for one config and env, built once on the host.

    Holds everything static that one iteration is made of: the config, the env, the SAC
    networks and optimisers, the classifier and its optimiser, the static `Schedule` and
    the `HostConstants`. Its `init`, `step` and `evaluate` are pure functions of one
    run's state; `jit_step` and `jit_evaluate` compile them over the run axis: the
    sweep's arms x the seeds (`d2c_jax.training.sweep`), one run per seed without a sweep.
    """

    def __init__(self, cfg: config_lib.TrainConfig, env: envs.GoalEnv):
        self.cfg = cfg
        self.env = env
        self.run_configs = sweep.run_configs(cfg)  # one per run, in run-axis order
        self.num_runs = len(self.run_configs)
        self.sac_nets = networks.make_networks(cfg.sac, env)
        self.sac_optimizers = sac.make_optimizers()
        self.classifier_net = classifier.make_classifier(cfg.classifier, env)
        self.classifier_optimizer = classifier.make_optimizer()
        self.schedule = make_schedule(cfg, env.horizon)
        # Swept hyperparameters that switch computations on: the program holds them
        # when any run uses them, and the traced value makes them a no-op elsewhere.
        uses_goal_value = any(c.curriculum.goal_value_weight != 0 for c in self.run_configs)
        self.rewards = tuple(sorted({interface.train_reward(c) for c in self.run_configs}))
        self.curriculum = interface.make_curriculum(cfg, env, self.classifier_net, uses_goal_value)
        self.constants = host_constants(env, self.curriculum.needs_start_obs)
        # Episodes per call of the episode loop, per run: a cap on CPU only, where jaxlib's
        # batched Cholesky (MJX's Newton solver) deadlocks above it (`rollout.MAX_CPU_ENV_BATCH`).
        self.episode_batch = rollout.max_episodes_per_call(jax.default_backend(), self.num_runs)

    # --- state ----------------------------------------------------------------------

    def init(self, key: jax.Array, hp: Hyperparams | None = None) -> TrainState:
        """A fresh TrainState for one run: its seed's key and its hyperparameters (default:
        the config's). vmap it over runs for a sweep (`init_runs`)."""
        cfg, env = self.cfg, self.env
        key, k_sac, k_clf, k_des = jax.random.split(key, 4)
        hp = hyperparams(cfg) if hp is None else hp
        return TrainState(
            sac=sac.init_sac(self.sac_nets, self.sac_optimizers, env, hp.sac, k_sac),
            classifier=classifier.init_classifier(
                self.classifier_net, self.classifier_optimizer, env.goal_dim, k_clf
            ),
            replay=replay.init_replay(
                cfg.replay, env.obs_dim, env.action_dim, env.goal_dim, env.horizon
            ),
            hparams=jax.tree.map(jnp.asarray, hp),
            # fold_in, not a split: D2C's key stream is the one it had before the interface
            curriculum_state=self.curriculum.init(jax.random.fold_in(key, 1)),
            desired=curriculum.desired_examples(env, cfg.curriculum.examples_per_mode, k_des),
            curriculum_goals=jnp.zeros((cfg.curriculum.n_slots, env.goal_dim), jnp.float32),
            matching_metrics={k: jnp.zeros((), jnp.float32) for k in curriculum.METRIC_KEYS},
            key=key,
            iteration=jnp.zeros((), jnp.int32),
            env_steps=jnp.zeros((), jnp.int32),
        )

    def init_runs(self, run_ids=None) -> TrainState:
        """TrainStates of the given runs (default: all, 0..num_runs-1), stacked on a
        leading run axis (jitted). Run r has its arm's hyperparameters and seed
        S + r % N, so it equals the single run of that arm and seed."""
        run_ids = range(self.num_runs) if run_ids is None else run_ids
        configs = [self.run_configs[r] for r in run_ids]
        keys = jnp.stack([jax.random.key(c.seed) for c in configs])
        hps = jax.tree.map(lambda *xs: np.stack(xs), *[hyperparams(c) for c in configs])
        return jax.jit(jax.vmap(self.init))(keys, hps)

    def init_seeds(self) -> TrainState:
        """All runs' TrainStates (`init_runs`): seeds S..S+N-1 when nothing is swept."""
        return self.init_runs()

    def policy(self, sac_state: sac.SACState, deterministic: bool = False) -> rollout.Policy:
        """The actor of one seed's SAC state; tanh of the mean when deterministic (SPEC §7)."""
        return sac.make_policy(self.sac_nets, sac_state, self.env, deterministic)

    # --- one iteration --------------------------------------------------------------

    def step(self, ts: TrainState) -> tuple[TrainState, dict]:
        """One D2C iteration for one seed: curriculum -> collect -> store -> updates.

        Warm-up (SPEC §2: random actions) while ts.iteration < schedule.warmup_iterations.
        """
        key, k_cur, k_col, k_upd = jax.random.split(ts.key, 4)
        goals, cur_metrics, cur_state = self.curriculum_goals(ts, k_cur)
        warmup = ts.iteration < self.schedule.warmup_iterations
        episodes = self.collect_episodes(ts, self.env_goals(ts, goals), warmup, k_col)
        ts = ts.replace(replay=replay.insert_episodes(ts.replay, episodes))
        # The curriculum learns from the stored episodes (its own key: D2C's stream stays).
        inputs = self.curriculum_inputs(ts, key=jax.random.fold_in(k_cur, 2))
        cur_state, observe_metrics = self.curriculum.observe(cur_state, episodes, inputs)
        ts = ts.replace(
            curriculum_state=cur_state,
            curriculum_goals=goals,
            matching_metrics=cur_metrics,
            key=key,
            iteration=ts.iteration + 1,
            env_steps=ts.env_steps + self.schedule.env_steps,
        )
        ts, upd_metrics = self.updates(ts, k_upd)
        metrics = {**cur_metrics, **observe_metrics, **upd_metrics}
        return ts, {**metrics, **self._episode_metrics(ts, episodes)}

    def _episode_metrics(self, ts: TrainState, episodes: rollout.Episodes) -> dict:
        """The "train/*" metrics of this iteration's episodes and the parameter check."""
        return {
            "train/success_rate": episodes.success.any(axis=1).mean(),
            "train/walk_share": 1.0 - episodes.walk_start.mean() / self.env.horizon,
            "train/still_share": rollout.stayed_at_start(
                episodes.achieved_goal, self.env.success_radius
            ).mean(),
            "train/final_distance": envs.goal_distance(
                episodes.achieved_goal[:, -1], episodes.goal[:, -1]
            ).mean(),
            "health/params_finite": params_finite(ts),
        }

    def evaluate(self, ts: TrainState, key: jax.Array) -> dict:
        """SPEC §7 evaluation of one seed: "eval/success" and "eval/success/<k>" per mode."""
        policy = self.policy(ts.sac, deterministic=True)
        per_mode = rollout.evaluate(
            self.env, policy, self.cfg.eval_episodes, key, self.episode_batch
        )
        metrics = {"eval/success": per_mode.mean()}
        return {**metrics, **{f"eval/success/{k}": per_mode[k] for k in range(self.env.n_modes)}}

    # --- curriculum -----------------------------------------------------------------

    def curriculum_goals(self, ts: TrainState, key) -> tuple[jax.Array, dict, object]:
        """Goals (K, d) of this iteration, their `curriculum/*` metrics and the curriculum's
        state: a new proposal every `schedule.rematch_every` iterations, else the held
        goals (their metrics and the state with them).

        `lax.cond` on the iteration count: a real branch for one seed; under vmap over
        seeds it becomes a select and matches every iteration, as before.
        """
        if self.schedule.rematch_every == 1:
            return self.match(ts, key)
        due = ts.iteration % self.schedule.rematch_every == 0
        held = lambda: (ts.curriculum_goals, ts.matching_metrics, ts.curriculum_state)  # noqa: E731
        return jax.lax.cond(due, lambda: self.match(ts, key), held)

    def match(self, ts: TrainState, key) -> tuple[jax.Array, dict, object]:
        """A new curriculum: `propose` of the run's curriculum (`interface.Curriculum`)."""
        inputs = self.curriculum_inputs(ts, pool_key=jax.random.fold_in(key, 1))
        goals, metrics, state = self.curriculum.propose(ts.curriculum_state, inputs, key)
        return goals, jax.tree.map(lambda x: x.astype(jnp.float32), metrics), state

    def curriculum_inputs(
        self, ts: TrainState, pool_key=None, key=None
    ) -> interface.CurriculumInputs:
        """What the curriculum reads (`interface.CurriculumInputs`): the matching pool,
        drawn with `pool_key` (None: the P most recent episodes only), the classifier,
        the buffer, the desired examples, the iteration, the curriculum's own `key` and,
        where it asks for them, the pool's observations and the critic's V(s, g)."""
        cur, pool_size = self.curriculum, self.cfg.curriculum.pool_size
        if pool_key is None:
            slots, pool_valid = replay.recent_episode_slots(ts.replay, pool_size)
        else:
            slots, pool_valid = self._matching_pool(ts, pool_key)
        start_obs = self.constants.start_obs
        pool_ag = ts.replay.achieved_goal[slots]  # (P + A, H + 1, d)
        pool_obs = ts.replay.obs[slots] if cur.needs_pool_obs else None
        if self.cfg.curriculum.pool_phase == "curriculum_phase":
            last_kept = ts.replay.walk_start[slots] + self.cfg.curriculum.pool_walk_steps
            pool_ag = replay.hold_after(pool_ag, last_kept)
            if pool_obs is not None:
                pool_obs = replay.hold_after(pool_obs, last_kept)
        return interface.CurriculumInputs(
            pool_ag=pool_ag,
            pool_obs=pool_obs,
            pool_valid=pool_valid,
            start_goal=jnp.asarray(self.constants.start_goal),
            start_obs=None if start_obs is None else jnp.asarray(start_obs),
            classifier_params=ts.classifier.params,
            value_fn=self._value_fn(ts) if cur.needs_value else None,
            hp=ts.hparams.curriculum,
            replay=ts.replay,
            desired=ts.desired,
            iteration=ts.iteration,
            relabel_prob=ts.hparams.relabel_prob,
            policy=self.policy(ts.sac),
            key=key,
        )

    def _matching_pool(self, ts: TrainState, key) -> tuple[jax.Array, jax.Array]:
        """The curriculum's pool: the P most recent episodes, then `archive_size` episodes
        drawn from the whole buffer (issue 10 rule 5), towards rarely visited outcomes
        with `archive_rarity` > 0.

        Archive rows beyond the episodes stored so far repeat the most recent episode, so
        the pool counts as full (the warm-up ends) as soon as P episodes exist.

        Returns:
          buffer slots (P + A,) int32 and valid (P + A,) bool.
        """
        cur = self.cfg.curriculum
        slots, valid = replay.recent_episode_slots(ts.replay, cur.pool_size)
        if cur.archive_size == 0:
            return slots, valid
        log_weights = None
        if cur.archive_rarity > 0:  # else the uniform draw, with the key it always had
            key, k_weights = jax.random.split(key)
            log_weights = self._archive_log_weights(ts, k_weights)
        archived, archived_valid = replay.archived_episode_slots(
            ts.replay, cur.archive_size, key, log_weights
        )
        archived = jnp.where(archived_valid, archived, slots[0])
        return (
            jnp.concatenate([slots, archived]),
            jnp.concatenate([valid, jnp.broadcast_to(valid[0], archived_valid.shape)]),
        )

    def _archive_log_weights(self, ts: TrainState, key) -> jax.Array:
        """(n_slots,) log-weights of the archive draw: the rarity of each episode's final
        state among visited states (`curriculum.rarity_log_weights`)."""
        rarity = self.cfg.curriculum.archive_rarity
        visited = replay.sample_achieved_goals(ts.replay, _RARITY_POINTS, key)
        outcomes = ts.replay.achieved_goal[:, -1]  # (n_slots, d)
        return curriculum.rarity_log_weights(self.env, outcomes, visited, rarity)

    def _value_fn(self, ts: TrainState) -> interface.StateGoalValueFn:
        """The critic's V(s, g) = min_i Q_i(s, pi(s, g), g) (`sac.state_value`)."""
        return lambda obs, goals: sac.state_value(self.sac_nets, ts.sac, self.env, obs, goals)

    def env_goals(self, ts: TrainState, goals: jax.Array) -> jax.Array:
        """(num_envs, d) goals: env i of the r-th iteration since the matching takes slot
        (i + r * num_envs) mod K, so held goals are used in turn rather than the first
        ones."""
        n = self.cfg.num_envs
        rounds = ts.iteration % self.schedule.rematch_every
        return goals[(jnp.arange(n) + rounds * n) % goals.shape[0]]

    # --- episodes -------------------------------------------------------------------

    def collect_episodes(self, ts: TrainState, goals, warmup, key) -> rollout.Episodes:
        """Episodes of this iteration: random actions while `warmup` (() bool), else the
        actor; `jnp.where` picks the action (the actor's forward pass is cheap next to
        the updates), so warm-up and training iterations are one compiled program."""
        cfg, env = self.cfg, self.env
        actor = self.policy(ts.sac)
        uniform = rollout.random_policy(env.action_dim)

        def policy(obs, goal, key):
            k_actor, k_uniform = jax.random.split(key)
            return jnp.where(warmup, uniform(obs, goal, k_uniform), actor(obs, goal, k_actor))

        inputs = self.curriculum_inputs(ts, key=jax.random.fold_in(key, 3))
        next_goal = self.curriculum.next_goal(ts.curriculum_state, inputs)
        switch_every = 0 if next_goal is None else cfg.curriculum.post_success_switch_every
        return rollout.collect(
            env, policy, next_goal, goals, cfg.num_envs, key, switch_every, self.episode_batch
        )

    # --- updates --------------------------------------------------------------------

    def updates(self, ts: TrainState, key) -> tuple[TrainState, dict]:
        """M SAC updates interleaved evenly with C classifier updates (SPEC §2 step 4).

        With n = M / block_size SAC blocks: C rounds of (1 classifier update, n // C SAC
        blocks), then the n mod C remaining blocks; all counts are static.
        """
        n = self.schedule.sac_updates // sac.block_size(self.cfg.sac)
        c = self.schedule.classifier_updates
        k_rounds, k_rest = jax.random.split(key)
        if c == 0:
            return self.sac_blocks(ts, n, k_rounds)

        def one_round(ts, k):
            k_clf, k_sac = jax.random.split(k)
            ts, clf_metrics = self.classifier_update(ts, k_clf)
            ts, sac_metrics = self.sac_blocks(ts, n // c, k_sac)
            return ts, {**clf_metrics, **sac_metrics}

        ts, metrics = jax.lax.scan(one_round, ts, jax.random.split(k_rounds, c))
        ts, rest = self.sac_blocks(ts, n % c, k_rest)
        # SAC metrics: the rounds' mean where rounds hold SAC updates, else the remainder's.
        return ts, {**rest, **jax.tree.map(jnp.mean, metrics)}

    def reward_fn(self, ts: TrainState) -> RewardFn:
        """The reward of SPEC §4: the curriculum's intrinsic reward (D2C's p_pseudo), or
        the sparse one where the traced `ts.hparams.sparse_reward` says so; only the
        rewards some run uses are computed."""
        sparse = ts.hparams.sparse_reward
        sparse_fn = her.sparse_reward_fn(self.env)
        intrinsic_fn = self.curriculum.intrinsic_reward(ts.curriculum_state, ts.classifier.params)
        if self.rewards == ("sparse",):
            return sparse_fn
        if self.rewards == ("intrinsic",):
            return intrinsic_fn
        return lambda ag, g: jnp.where(sparse, sparse_fn(ag, g), intrinsic_fn(ag, g))

    def terminal_fn(self) -> RewardFn | None:
        """Where the critic stops bootstrapping: success of the relabelled goal for a
        curriculum whose own code ends there (OUTPACE) or with `sac.terminal_on_success`,
        else None: no terminal (SPEC §4)."""
        terminal = self.curriculum.terminal_on_success or self.cfg.sac.terminal_on_success
        return her.sparse_reward_fn(self.env) if terminal else None

    def sac_blocks(self, ts: TrainState, n: int, key) -> tuple[TrainState, dict]:
        """`n` blocks of `sac.block_size` SAC updates on HER batches rewarded by the current
        classifier (`sac_loop.sac_blocks`); the mean "sac/*" metrics."""
        if n == 0:
            return ts, {}
        sac_state, metrics = sac_loop.sac_blocks(
            self.cfg, self.env, self.sac_nets, self.sac_optimizers, ts.hparams, ts.sac,
            ts.replay, self.reward_fn(ts), self.terminal_fn(), n, key,
        )  # fmt: skip
        return ts.replace(sac=sac_state), metrics

    def classifier_update(self, ts: TrainState, key) -> tuple[TrainState, dict]:
        """One Eq. 5 update: negatives are achieved goals of random buffer states (of the
        curriculum phase only, with `negatives="curriculum_phase"`)."""
        cfg, hp = self.cfg.classifier, ts.hparams.classifier
        k_states, k_batch = jax.random.split(key)
        states = replay.sample_achieved_goals(
            ts.replay,
            cfg.batch_size,
            k_states,
            curriculum_phase_only=cfg.negatives == "curriculum_phase",
        )
        batch = classifier.sample_batch(cfg, self.env, hp, states, ts.desired, k_batch)
        new_clf, metrics = classifier.update_classifier(
            cfg, self.classifier_net, self.classifier_optimizer, hp, ts.classifier, batch
        )
        return ts.replace(classifier=new_clf), metrics


def params_finite(ts: TrainState) -> jax.Array:
    """() bool: every SAC and classifier parameter is finite."""
    leaves = jax.tree.leaves((ts.sac, ts.classifier.params))
    floats = [jnp.all(jnp.isfinite(x)) for x in leaves if jnp.issubdtype(x.dtype, jnp.floating)]
    return jnp.all(jnp.stack(floats))


def make_train_step(cfg: config_lib.TrainConfig, env: envs.GoalEnv):
    """`jit_step` of a new `Agent(cfg, env)`: step(ts) -> (ts, metrics) over all runs."""
    return jit_step(Agent(cfg, env))
