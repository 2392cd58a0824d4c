"""OUTPACE (Cho, Lee & Kim, ICLR 2023) as a curriculum of our interface (`--algo outpace`).

Two learned parts live in the curriculum's state and train in `observe`:
- the meta-NML success classifier (`meta_nml`): p_NML(1 | x), ~0.5 where x is
  unexplored, ~1 at the desired examples, ~0 where the agent has been;
- the AIM temporal-distance potential (`aim`): D(x, g), rising towards g in time steps.

The SAC reward is OUTPACE's normalised AIM reward (D(phi(s'), g) - mean) / (2 std).
The curriculum (outpace_official hgg/hgg.py, cost type meta_nml_aim_f) scores the states
of each pool trajectory by

    c_t = -log p_NML(1 | s_t) - v_t * D_max (1 - gamma) / L,

v_t = -D(s_0, s_t) min-max normalised to [-1, 1] over the pool; a trajectory costs min_t
c_t and offers that state. The cost does not depend on the desired example, so the
matching takes the K cheapest distinct trajectories. Each goal is its state plus
N(0, sigma^2). After success, OUTPACE's random walk scores its candidates by p_NML.
docs/BASELINES.md states every formula with its file and line.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import optax
from flax import struct

from d2c_jax.core import her, replay
from d2c_jax.core.types import Metrics, RewardFn
from d2c_jax.curricula import aim, curriculum, goal_switch, meta_nml
from d2c_jax.curricula.interface import Curriculum, CurriculumInputs, GoalSwitch

# The log of p_NML is clamped as torch's BCELoss clamps it (OUTPACE computes -log p so).
_MIN_LOG = -100.0


@struct.dataclass
class OutpaceState:
    """OUTPACE's learned parts (one run; leading run axis when vmapped)."""

    nml_params: dict  # meta-NML classifier parameters
    nml_opt: optax.OptState  # its meta-training Adam state
    aim_params: dict  # AIM ensemble parameters (leading member axis inside)
    aim_opt: optax.OptState  # their Adam state
    reward_mean: jax.Array  # () float32 the AIM reward's offset (max + 0.1)
    reward_std: jax.Array  # () float32 its scale (std + 0.1)
    nml_loss: jax.Array  # () float32 the last meta-training round's mean meta-test loss


class OutpaceCurriculum(Curriculum):
    """OUTPACE's curriculum, reward and random walk (module docstring)."""

    reward = "intrinsic"  # its own: the normalised AIM reward
    uses_classifier = False  # meta-NML replaces D2C's ensemble
    # Its critic stops bootstrapping at success of the relabelled goal (outpace_official
    # config_outpace.yaml: done_on_success, consider_done_true_in_critic; outpacesac.py
    # update_critic). Its AIM reward is negative everywhere (mean = max + 0.1), so without
    # that terminal the return is best where the potential peaks, which need not be g.
    terminal_on_success = True

    def __init__(self, cfg, env, classifier_net, uses_goal_value: bool = False):
        super().__init__(cfg, env, classifier_net, uses_goal_value)
        o = cfg.outpace
        self.nml_net = meta_nml.Classifier(o.nml_hidden_sizes, o.nml_input_scale)
        self.nml_optimizer = optax.adam(o.nml_lr)
        self.nml = meta_nml.MetaNMLSettings(
            inner_step=o.nml_inner_step,
            context_points=o.nml_context_points,
            query_weight_inner=o.nml_query_weight_inner,
            query_weight_outer=o.nml_query_weight_outer,
            distance_scale=o.nml_input_scale,
        )
        self.aim_net = aim.PotentialEnsemble(
            o.aim_members, o.aim_hidden_sizes, tuple(env.goal_low), tuple(env.goal_high)
        )
        self.aim_optimizer = optax.adam(o.aim_lr)
        steps = cfg.num_envs * env.horizon  # env steps per iteration (SPEC §2's E)
        self.aim_steps = max(1, round(o.aim_steps_per_1000 * steps / 1000))
        self.nml_every = max(1, round(o.nml_every / steps))

    # --- state ------------------------------------------------------------------------

    def init(self, key) -> OutpaceState:
        k_nml, k_aim = jax.random.split(key)
        d = self.env.goal_dim
        nml_params = self.nml_net.init(k_nml, jnp.zeros((1, d)))
        aim_params = self.aim_net.init(k_aim, jnp.zeros((1, d)), jnp.zeros((1, d)))
        return OutpaceState(
            nml_params=nml_params,
            nml_opt=self.nml_optimizer.init(nml_params),
            aim_params=aim_params,
            aim_opt=self.aim_optimizer.init(aim_params),
            reward_mean=jnp.zeros((), jnp.float32),  # OUTPACE's initial normalisers
            reward_std=jnp.ones((), jnp.float32),
            nml_loss=jnp.zeros((), jnp.float32),
        )

    # --- what the classifier and the potential learn from ----------------------------

    def labelled_points(self, inputs: CurriculumInputs, n: int, key) -> tuple:
        """n goal-space points, half visited achieved goals (label 0; curriculum phase
        only, as OUTPACE's main buffer), half desired examples (label 1): (n, d), (n,)."""
        k_neg, k_pos = jax.random.split(key)
        half = n // 2
        negatives = replay.sample_achieved_goals(
            inputs.replay, n - half, k_neg, curriculum_phase_only=True
        )
        desired = inputs.desired.reshape(-1, inputs.desired.shape[-1])
        positives = desired[jax.random.randint(k_pos, (half,), 0, desired.shape[0])]
        labels = jnp.concatenate([jnp.zeros(n - half, jnp.int32), jnp.ones(half, jnp.int32)])
        return jnp.concatenate([negatives, positives]), labels

    def aim_batch(self, inputs: CurriculumInputs, key) -> tuple:
        """(phi(s), phi(s'), g, x+) of curriculum-phase transitions, g relabelled to a
        future achieved goal with HER's probability; x+ = g + N(0, s^2) * mask."""
        k_tr, k_fut, k_coin, k_noise = jax.random.split(key, 4)
        buf, n = inputs.replay, self.cfg.outpace.aim_batch_size
        ep, t = replay.sample_phase_steps(buf, n, k_tr, walk=False)
        future = her.future_goals(buf, ep, t, k_fut)
        relabel = jax.random.bernoulli(k_coin, inputs.relabel_prob, (n,))[:, None]
        goal = jnp.where(relabel, future, buf.goal[ep, t])
        mask = jnp.asarray(self.env.goal_noise_mask, jnp.float32)
        noise = jax.random.normal(k_noise, goal.shape) * self.cfg.outpace.aim_target_noise
        return buf.achieved_goal[ep, t], buf.achieved_goal[ep, t + 1], goal, goal + noise * mask

    def observe(self, state: OutpaceState, episodes, inputs: CurriculumInputs):
        """AIM updates every iteration (10 per 1000 env steps) and, every `nml_every`
        iterations and in the first `nml_initial_rounds`, a meta-NML round."""
        del episodes
        k_aim, k_nml = jax.random.split(inputs.key)
        state, aim_metrics = self._train_aim(state, inputs, k_aim)
        due = (inputs.iteration < self.cfg.outpace.nml_initial_rounds) | (
            inputs.iteration % self.nml_every == 0
        )
        # A real branch for one run (under vmap over runs it becomes a select).
        state = jax.lax.cond(due, lambda: self._train_nml(state, inputs, k_nml), lambda: state)
        return state, {**aim_metrics, "outpace/nml_loss": state.nml_loss}

    def _train_aim(self, state: OutpaceState, inputs, key) -> tuple[OutpaceState, Metrics]:
        o = self.cfg.outpace

        def one(carry, k):
            params, opt = carry
            batch = self.aim_batch(inputs, k)
            params, opt, loss, values = aim.update(
                self.aim_net, self.aim_optimizer, params, opt, batch,
                o.aim_lipschitz, o.aim_penalty,
            )  # fmt: skip
            return (params, opt), (loss, values.mean(axis=1))  # (2, B): ensemble means

        keys = jax.random.split(key, self.aim_steps)
        (params, opt), (losses, values) = jax.lax.scan(one, (state.aim_params, state.aim_opt), keys)
        mean, std = aim.reward_statistics(values, o.aim_reward_offset)
        state = state.replace(aim_params=params, aim_opt=opt, reward_mean=mean, reward_std=std)
        return state, {"outpace/aim_loss": losses.mean(), "outpace/reward_std": std}

    def _train_nml(self, state: OutpaceState, inputs, key) -> OutpaceState:
        o = self.cfg.outpace
        k_train, k_test, k_steps = jax.random.split(key, 3)
        train = self.labelled_points(inputs, o.nml_train_points, k_train)
        test = self.labelled_points(inputs, o.nml_test_points, k_test)

        def one(carry, k):
            params, opt = carry
            params, opt, loss = meta_nml.meta_train_step(
                self.nml_net, self.nml_optimizer, params, opt, train, test, k, self.nml,
                o.nml_tasks_per_step,
            )  # fmt: skip
            return (params, opt), loss

        keys = jax.random.split(k_steps, o.nml_steps_per_round)
        (params, opt), losses = jax.lax.scan(one, (state.nml_params, state.nml_opt), keys)
        return state.replace(nml_params=params, nml_opt=opt, nml_loss=losses.mean())

    # --- reward, curriculum, random walk ---------------------------------------------

    def intrinsic_reward(self, state: OutpaceState, classifier_params) -> RewardFn:
        del classifier_params

        def reward_fn(ag_next, goal):
            return aim.intrinsic_reward(
                self.aim_net, state.aim_params, ag_next, goal, state.reward_mean, state.reward_std
            )

        return reward_fn

    def nml_probabilities(self, state: OutpaceState, inputs, points, key) -> jax.Array:
        """p_NML(1 | x) of points (Q, d), adapting on a fresh labelled pool: (Q,)."""
        k_pool, k_ctx = jax.random.split(key)
        pool = self.labelled_points(inputs, self.cfg.outpace.nml_test_points, k_pool)
        return meta_nml.nml_probabilities(
            self.nml_net, state.nml_params, points, *pool, k_ctx, self.nml
        )

    def cost(self, state: OutpaceState, inputs, traj, key) -> jax.Array:
        """OUTPACE's cost c_t of each pool state (module docstring): traj (P, T', d) -> (P, T')."""
        o, gamma = self.cfg.outpace, self.cfg.sac.gamma
        start = jnp.broadcast_to(inputs.pool_ag[:, :1], traj.shape)
        value = -aim.potential(self.aim_net, state.aim_params, start, traj)  # (P, T')
        valid = inputs.pool_valid[:, None]
        lo = jnp.min(jnp.where(valid, value, jnp.inf))
        hi = jnp.max(jnp.where(valid, value, -jnp.inf))
        scaled = 2.0 * ((value - lo) / (hi - lo + 1e-5) - 0.5)
        p = self.nml_probabilities(state, inputs, traj.reshape(-1, traj.shape[-1]), key)
        log_p = jnp.maximum(jnp.log(p), _MIN_LOG).reshape(traj.shape[:2])
        d_max = curriculum.start_to_desired_distance(self.env, inputs.start_goal)
        return -log_p - scaled * d_max * (1.0 - gamma) / o.cost_lipschitz

    def propose(self, state: OutpaceState, inputs: CurriculumInputs, key):
        cur, env = self.cfg.curriculum, self.env
        k_slots, k_cost, k_noise, k_warm = jax.random.split(key, 4)
        slots = curriculum.goal_slots(env, cur.n_slots, k_slots)  # for the distance metric
        traj = curriculum.subsample(inputs.pool_ag, cur.cost_stride, cur.pool_tail_fraction)
        cost_t = self.cost(state, inputs, traj, k_cost)  # (P, T')
        best = jnp.argmin(cost_t, axis=-1)
        pool_index = jnp.arange(traj.shape[0])
        # The cost does not depend on the slot: every row is the trajectories' cost.
        shape = (cur.n_slots,) + best.shape
        cost = jnp.broadcast_to(cost_t[pool_index, best], shape)  # (K, P)
        candidates = jnp.broadcast_to(traj[pool_index, best], shape + traj.shape[-1:])
        mask = jnp.asarray(env.goal_noise_mask, jnp.float32)
        noise = jax.random.normal(k_noise, slots.shape) * self.cfg.outpace.goal_noise_std * mask
        goals, matched, full, converged = curriculum.assign_goals(
            cur, env, cost, candidates, inputs.pool_ag, inputs.pool_valid, inputs.start_goal,
            noise, k_warm,
        )  # fmt: skip
        metrics = curriculum.proposal_metrics(goals, slots, matched, full, converged)
        return goals, metrics, state

    def next_goal(self, state: OutpaceState, inputs: CurriculumInputs) -> GoalSwitch:
        """OUTPACE's random walk: candidates phi(s) + U(-r, r), scored by p_NML, the
        threshold rule and softmax of `goal_switch.post_success_goal`'s "outpace" rule."""
        cfg, env = self.cfg.curriculum, self.env
        k_pool, k_ctx = jax.random.split(inputs.key)
        # One labelled pool per iteration (OUTPACE draws one per call; the draws are iid).
        pool = self.labelled_points(inputs, self.cfg.outpace.nml_test_points, k_pool)

        def score(points, key):
            return meta_nml.nml_probabilities(
                self.nml_net, state.nml_params, points, *pool, key, self.nml
            )

        def next_goal(achieved_goal, key):
            return goal_switch.walk_goal(cfg, env, achieved_goal, key, inputs.hp, score)

        return next_goal
