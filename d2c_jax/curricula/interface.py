"""One interface for every curriculum (issue 18): D2C, its ablations and the baselines.

A curriculum is a small object built once on the host for one (config, env); its
methods are pure, jittable functions of its own state pytree, so every method runs
inside the one jitted iteration, under vmap over runs:

  init(key) -> state                 its own evolving state (checkpointed with the run)
  propose(state, inputs, key) -> (goals (K, d), metrics, state)  goals for the next episodes
  observe(state, episodes, inputs) -> (state, metrics)          learn from the new episodes

and it says what it trains with: `reward` ("intrinsic": its own reward, D2C's p_pseudo by
default (`intrinsic_reward`); or "sparse"), `next_goal` (the goal switch after success,
or None to keep the goal) and `uses_classifier` (whether D2C's classifier ensemble is
trained at all).

Implemented here: `MatchingCurriculum` (D2C, Eq. 6-7, and its "+Value" ablation),
`DesiredExamples` (D2C's "no curriculum" ablation, and HER: episodes conditioned on
the desired examples); elsewhere in `d2c_jax.curricula`: `hgg`, `outpace`, `teachers`
(PLR, ALP-GMM), `vds` and `currot`. `curriculum_class(cfg)` maps `cfg.algo` to one.
"""

from __future__ import annotations

from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp

from d2c_jax import config as config_lib
from d2c_jax.core.types import Metrics, RewardFn
from d2c_jax.curricula import classifier as classifier_lib
from d2c_jax.curricula import curriculum, goal_switch
from d2c_jax.curricula.classifier import Classifier
from envs import GoalEnv

# value_fn(obs (..., o), goals (..., d)) -> (...) the critic's V(s, g) = min_i Q_i(s, pi(s, g), g)
StateGoalValueFn = Callable[[jax.Array, jax.Array], jax.Array]
# next_goal(achieved_goal (d,), key) -> (d,) the goal after success (rollout.GoalSwitch)
GoalSwitch = Callable[[jax.Array, jax.Array], jax.Array]


class CurriculumInputs(NamedTuple):
    """What a curriculum may read, built by the agent each iteration (one run's values)."""

    pool_ag: jax.Array  # (P, T, d) achieved goals of the matching pool's episodes
    pool_obs: jax.Array | None  # (P, T, o) their observations; None unless `needs_pool_obs`
    pool_valid: jax.Array  # (P,) bool which pool entries hold episodes
    start_goal: jax.Array  # (d,) phi of the start state (host constant)
    start_obs: jax.Array | None  # (o,) a start observation; None unless `needs_start_obs`
    classifier_params: dict  # the classifier ensemble's parameters
    value_fn: StateGoalValueFn | None  # the critic's V(s, g); None unless `needs_value`
    hp: curriculum.CurriculumHyperparams  # the traced curriculum hyperparameters
    replay: object = None  # the replay buffer (`replay.ReplayState`), for `observe`
    desired: jax.Array | None = None  # (n_modes, n, d) the desired examples
    iteration: jax.Array | None = None  # () int32 iterations done before this one
    relabel_prob: jax.Array | None = None  # () float32 HER's relabelling probability
    policy: Callable | None = None  # the SAC actor: policy(obs, goal, key) -> action (sampled)
    key: jax.Array | None = None  # a PRNG key of the curriculum's own


class Curriculum:
    """The interface (see the module docstring). Subclasses set the class attributes and
    implement `propose`; `init` and `observe` default to a stateless curriculum."""

    reward: str | None = None  # "intrinsic" | "sparse"; None: the config's `reward`
    uses_classifier: bool = False  # the classifier ensemble is trained (and may be read)
    needs_pool_obs: bool = False  # `propose` reads inputs.pool_obs
    needs_value: bool = False  # `propose` reads inputs.value_fn
    needs_start_obs: bool = False  # reads inputs.start_obs (a compiled reset on the host)
    # The critic's bootstrap stops where the relabelled goal is reached (OUTPACE's code);
    # False: no terminal on success (SPEC §4, decided).
    terminal_on_success: bool = False

    def __init__(
        self,
        cfg: config_lib.TrainConfig,
        env: GoalEnv,
        classifier_net: Classifier,
        uses_goal_value: bool = False,
    ):
        """`uses_goal_value`: some run of the sweep has D2C's beta != 0 (only D2C's
        matching reads it)."""
        self.cfg = cfg
        self.env = env
        self.classifier_net = classifier_net
        self.uses_goal_value = uses_goal_value

    def init(self, key: jax.Array):
        """The curriculum's own state (a pytree; None when it keeps none)."""
        del key
        return None

    def propose(self, state, inputs: CurriculumInputs, key) -> tuple[jax.Array, Metrics, object]:
        """(n_slots, d) goals for the next episodes, their metrics (exactly
        `curriculum.METRIC_KEYS`: they are held between proposals; a curriculum's own
        metrics come from `observe`) and the state (a teacher records what it proposed,
        to score it in `observe`)."""
        raise NotImplementedError

    def observe(self, state, episodes, inputs: CurriculumInputs) -> tuple[object, Metrics]:
        """The state after this iteration's episodes (`rollout.Episodes`, already in
        inputs.replay) and its metrics."""
        del episodes, inputs
        return state, {}

    def next_goal(self, state, inputs: CurriculumInputs) -> GoalSwitch | None:
        """The goal switch after success (SPEC §6), or None: keep the goal."""
        del state, inputs
        return None

    def intrinsic_reward(self, state, classifier_params: dict) -> RewardFn:
        """The "intrinsic" reward: D2C's p_pseudo(phi(s'); g) (SPEC §4) by default."""
        del state
        return classifier_lib.make_reward_fn(self.classifier_net, classifier_params)


class D2CGoalSwitch:
    """Mixin: D2C's post-success goal choice (SPEC §6, Alg. 1 lines 8-9)."""

    def next_goal(self, state, inputs: CurriculumInputs) -> GoalSwitch:
        cfg, env, net = self.cfg.curriculum, self.env, self.classifier_net
        params, hp = inputs.classifier_params, inputs.hp

        def next_goal(achieved_goal, key):
            return goal_switch.post_success_goal(cfg, env, net, params, achieved_goal, key, hp)

        return next_goal


class MatchingCurriculum(D2CGoalSwitch, Curriculum):
    """D2C (Eq. 6-7, `curriculum.propose`): slots matched to pool trajectories by the
    classifier's cost, then goal noise; the "+Value" ablation subtracts (1 - gamma)
    V(s0, phi(s)), and beta > 0 adds the critic's V(s, g_j+) tie-break."""

    reward = None
    uses_classifier = True

    def __init__(self, cfg, env, classifier_net, uses_goal_value: bool = False):
        super().__init__(cfg, env, classifier_net, uses_goal_value)
        self.needs_pool_obs = uses_goal_value
        self.needs_value = uses_goal_value or cfg.curriculum.variant == "value"
        self.needs_start_obs = cfg.curriculum.variant == "value"

    def propose(self, state, inputs: CurriculumInputs, key) -> tuple[jax.Array, Metrics, object]:
        start_value_fn = goal_value_fn = None
        if self.cfg.curriculum.variant == "value":
            start_value_fn = lambda goals: inputs.value_fn(inputs.start_obs, goals)  # noqa: E731
        if self.uses_goal_value:

            def goal_value_fn(obs, goal):
                return inputs.value_fn(obs, jnp.broadcast_to(goal, obs.shape[:-1] + goal.shape))

        goals, metrics = curriculum.propose(
            self.cfg.curriculum, self.env, self.classifier_net, inputs.classifier_params,
            inputs.pool_ag, inputs.pool_valid, inputs.start_goal, key, start_value_fn,
            gamma=self.cfg.sac.gamma, pool_obs=inputs.pool_obs, goal_value_fn=goal_value_fn,
            hp=inputs.hp,
        )  # fmt: skip
        return goals, metrics, state


class DesiredExamples(Curriculum):
    """Goals drawn straight from the desired examples (SPEC §5's slots): D2C's "no
    curriculum" ablation (intrinsic reward, D2C's goal switch) and HER alone (sparse
    reward, the goal kept for the whole episode)."""

    def propose(self, state, inputs: CurriculumInputs, key) -> tuple[jax.Array, Metrics, object]:
        del inputs
        slots = curriculum.goal_slots(self.env, self.cfg.curriculum.n_slots, key)
        return slots, curriculum.proposal_metrics(slots, slots, 0.0, True, True), state


class NoCurriculumAblation(D2CGoalSwitch, DesiredExamples):
    """D2C without its curriculum (`--curriculum.variant none`, appendix C)."""

    uses_classifier = True


class HERDesired(DesiredExamples):
    """HER alone (the paper's "HER" baseline): desired-example goals, sparse reward."""

    reward = config_lib.ALGO_REWARDS["her"]


def curriculum_class(cfg: config_lib.TrainConfig) -> type[Curriculum]:
    """The curriculum `cfg.algo` (and, for D2C, `cfg.curriculum.variant`) selects."""
    if cfg.algo == "hgg":
        from d2c_jax.curricula import hgg  # here: hgg builds on this module

        return hgg.HGGCurriculum
    if cfg.algo == "outpace":
        from d2c_jax.curricula import outpace  # here: outpace builds on this module

        return outpace.OutpaceCurriculum
    if cfg.algo in config_lib.TEACHER_ALGOS:
        from d2c_jax.curricula import currot, teachers, vds  # here: they build on this module

        return {"currot": currot.CurrotTeacher, "plr": teachers.PLRTeacher,
                "alp_gmm": teachers.ALPGMMTeacher, "vds": vds.VDSTeacher}[cfg.algo]  # fmt: skip
    if cfg.algo == "her":
        return HERDesired
    if cfg.curriculum.variant == "none":
        return NoCurriculumAblation
    return MatchingCurriculum


def make_curriculum(
    cfg: config_lib.TrainConfig,
    env: GoalEnv,
    classifier_net: Classifier,
    uses_goal_value: bool = False,
) -> Curriculum:
    """The curriculum of `curriculum_class(cfg)` for this env and classifier module."""
    return curriculum_class(cfg)(cfg, env, classifier_net, uses_goal_value)


def train_reward(cfg: config_lib.TrainConfig) -> str:
    """The reward a run trains with: its algorithm's fixed one, else `cfg.reward`."""
    return curriculum_class(cfg).reward or cfg.reward
