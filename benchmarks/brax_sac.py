"""brax's SAC on our MJX env: the JAX reference of the throughput benchmark (issue 21 §2).

    python -m benchmarks.brax_sac [--sizes small paper]
    python -m benchmarks.brax_sac --bare [--sizes small] [--rounds 7]

prints brax SAC's env steps/s and SAC updates/s on `medium_maze` (through
`envs.to_brax`); `python -m benchmarks.run --only throughput` puts them beside ours.
`--bare` times the two SAC updates alone, each `lax.scan`ned over BARE_UPDATES updates on
one fixed batch, alternating round by round, and prints each update's FLOPs (XLA's cost
analysis) and the rate it reaches: brax's update built from its own parts
(`sac.losses.make_losses`, `gradients.gradient_update_fn`, the order of its `sgd_step`:
alpha, critic, actor, target, each from the pre-update parameters) against ours
(`sac.update_sac_block` at the same settings). The difference between the bare and the
whole-loop ratios is what the training loops around the updates cost.

The settings are those of `benchmarks.trainer.sb3_settings`, which our rows use: the
SIZES widths and batch, `num_envs` = 4 parallel envs and one gradient step per env step,
so `grad_updates_per_step` = num_envs (brax steps every env once, then runs that many
updates). brax updates the critic, the actor, alpha and the target at every update, as
our rows are configured to. What brax does not do: HER relabelling (its buffer samples
stored transitions), the intrinsic reward, any curriculum.

Timing: brax's own `training/sps`, the env steps of one training epoch (a `lax.scan` of
`steps_per_epoch` actor steps, each followed by its updates, pmapped over the one CPU
device) over the epoch's wall-clock. The first epoch includes compilation and is not counted;
`benchmarks.run` takes the best of the epochs after it, as it takes the best of our timed
rounds after compiling.
"""

from __future__ import annotations

import argparse
import functools
import statistics
import sys
import time
from typing import Callable

import envs
from benchmarks import brax_compat, results
from benchmarks.sac_update import SIZES, size_label

NUM_ENVS = 4
"""Parallel envs, as in benchmarks.trainer.sb3_settings."""
BARE_UPDATES = 200
"""Updates per timed bare-update round."""
STEPS_PER_EPOCH = 500
"""Actor steps per timed epoch: 2,000 env steps and 2,000 updates with 4 envs, about one
of our matching cycles."""


def epoch_rates(
    size: str,
    env_name: str = "medium_maze",
    timed_epochs: int = 2,
    after_epoch: Callable[[], None] = lambda: None,
    steps_per_epoch: int = STEPS_PER_EPOCH,
    seed: int = 0,
) -> list[float]:
    """brax SAC's env steps/s (= updates/s: one per env step) of each timed epoch on
    `env_name` at SIZES[size].

    Runs one untimed epoch (it compiles) and `timed_epochs` timed ones of `steps_per_epoch`
    actor steps, after a prefill of one batch. `after_epoch()` runs before each timed
    epoch (in brax's progress callback, outside its timing): `benchmarks.run` times our rows there,
    so that both tools alternate on the same machine state.
    """
    from brax.training.agents.sac import networks as sac_networks
    from brax.training.agents.sac import train as sac_train

    brax_compat.install()  # brax 0.14.2 calls jax.device_put_replicated (benchmarks.brax_compat)
    hidden, batch = SIZES[size]
    env = envs.make(env_name)
    epochs = 1 + timed_epochs
    rates: list[float] = []

    def record(step: int, metrics: dict) -> None:
        if "training/sps" in metrics:  # not the evaluation before the first epoch
            rates.append(float(metrics["training/sps"]))
            if len(rates) < epochs:  # between epochs: as many rounds as timed epochs
                after_epoch()

    sac_train.train(
        envs.to_brax(env),
        # brax splits num_timesteps - prefill into (num_evals - 1) epochs of whole actor steps.
        num_timesteps=batch + epochs * steps_per_epoch * NUM_ENVS,
        episode_length=env.horizon,
        num_envs=NUM_ENVS,
        num_eval_envs=1,
        batch_size=batch,
        grad_updates_per_step=NUM_ENVS,
        min_replay_size=batch,
        max_replay_size=100_000,
        num_evals=1 + epochs,
        discounting=0.99,
        learning_rate=3e-4,
        deterministic_eval=True,
        seed=seed,
        network_factory=functools.partial(
            sac_networks.make_sac_networks, hidden_layer_sizes=tuple(hidden)
        ),
        progress_fn=record,
    )
    if len(rates) != epochs:
        raise RuntimeError(f"brax SAC reported {len(rates)} training epochs, expected {epochs}")
    return rates[1:]


def _brax_bare_update(hidden, feat_dim: int, act_dim: int, transitions, key):
    """brax's SAC update (alpha, critic and actor steps from the same parameters, then the
    target) on one fixed batch of brax `transitions`, and its initial state."""
    import jax
    import jax.numpy as jnp
    import optax
    from brax.training import gradients
    from brax.training.agents.sac import losses as sac_losses
    from brax.training.agents.sac import networks as sac_networks

    nets = sac_networks.make_sac_networks(feat_dim, act_dim, hidden_layer_sizes=tuple(hidden))
    alpha_loss, critic_loss, actor_loss = sac_losses.make_losses(nets, 1.0, 0.99, act_dim)
    adam = optax.adam(3e-4)
    alpha_step, critic_step, actor_step = (
        gradients.gradient_update_fn(loss, adam, pmap_axis_name=None)
        for loss in (alpha_loss, critic_loss, actor_loss)
    )

    def update(s, key):
        k_alpha, k_critic, k_actor = jax.random.split(key, 3)
        alpha = jnp.exp(s["log_alpha"])
        _, log_alpha, alpha_opt = alpha_step(
            s["log_alpha"], s["policy"], None, transitions, k_alpha, optimizer_state=s["alpha_opt"]
        )
        _, q, q_opt = critic_step(
            s["q"], s["policy"], None, s["target_q"], alpha, transitions, k_critic,
            optimizer_state=s["q_opt"],
        )  # fmt: skip
        _, policy, policy_opt = actor_step(
            s["policy"], None, s["q"], alpha, transitions, k_actor, optimizer_state=s["policy_opt"]
        )
        target_q = jax.tree.map(lambda t, p: t * 0.995 + p * 0.005, s["target_q"], q)
        new = dict(policy=policy, q=q, target_q=target_q, log_alpha=log_alpha)
        return {**new, "policy_opt": policy_opt, "q_opt": q_opt, "alpha_opt": alpha_opt}, None

    policy, q = nets.policy_network.init(key), nets.q_network.init(key)
    state = dict(
        policy=policy, q=q, target_q=q, log_alpha=jnp.zeros(()),
        policy_opt=adam.init(policy), q_opt=adam.init(q), alpha_opt=adam.init(jnp.zeros(())),
    )  # fmt: skip
    return update, state


def _ours_bare_update(cfg, agent, action, key):
    """Our SAC update (one block of one update, `sac.update_sac_block`) on one fixed batch
    of random observations and goals with `action` (B, act_dim), and its initial state."""
    import jax
    import jax.numpy as jnp

    from d2c_jax.core import sac
    from d2c_jax.core.types import Batch

    env, batch = agent.env, action.shape[0]
    # Only SAC's state: the agent's replay buffer (3M transitions) plays no part here.
    hp = sac.hyperparams(cfg.sac)
    state = sac.init_sac(agent.sac_nets, agent.sac_optimizers, env, hp, key)
    raw = jax.random.normal(key, (batch, env.obs_dim + env.goal_dim))
    zeros = jnp.zeros(batch)
    one_block = jax.tree.map(  # leaves (1, B, ...)
        lambda x: x[None],
        Batch(raw[:, : env.obs_dim], action, zeros, raw[:, : env.obs_dim] + 0.1,
              raw[:, env.obs_dim :], jnp.ones(batch)),
    )  # fmt: skip

    def update(s, key):
        s, _ = sac.update_sac_block(
            cfg.sac, agent.sac_nets, agent.sac_optimizers, hp, s, one_block, env, key
        )
        return s, None

    return update, state


def bare_update_ms(
    size: str, rounds: int, env_name: str = "medium_maze"
) -> tuple[dict[str, list], dict[str, float]]:
    """Milliseconds per SAC update of brax's update and of ours alone, `rounds` alternating
    rounds of BARE_UPDATES updates each on one fixed batch at SIZES[size]: name -> ms per
    round, and name -> FLOPs of one update (`update_flops`)."""
    import jax
    import jax.numpy as jnp
    from brax.training import types

    from benchmarks.trainer import throughput_configs
    from d2c_jax.core import networks
    from d2c_jax.training.agent import Agent

    hidden, batch = SIZES[size]
    cfg = throughput_configs(size, env_name)["SAC+HER"]
    agent = Agent(cfg, envs.make(env_name))
    feat_dim, act_dim = networks.feature_dim(agent.env), agent.env.action_dim
    keys = jax.random.split(jax.random.key(0), 4)
    obs, next_obs = (jax.random.normal(k, (batch, feat_dim)) for k in keys[:2])
    action = jnp.tanh(jax.random.normal(keys[2], (batch, act_dim)))
    zeros = jnp.zeros(batch)
    transitions = types.Transition(
        obs, action, zeros, jnp.ones(batch), next_obs, {"state_extras": {"truncation": zeros}}
    )
    updates = {
        "brax SAC": _brax_bare_update(hidden, feat_dim, act_dim, transitions, keys[3]),
        "d2c_jax": _ours_bare_update(cfg, agent, action, keys[3]),
    }
    flops = {name: update_flops(u, s, keys[0]) for name, (u, s) in updates.items()}
    return _alternating_ms(updates, rounds, keys[0]), flops


def update_flops(update, state, key) -> float:
    """Floating-point operations of one call of `update(state, key)`, as XLA's cost analysis
    of the compiled update counts them (matmuls at 2 per multiply-add, plus elementwise)."""
    import jax

    compiled = jax.jit(lambda s, k: update(s, k)[0]).lower(state, key).compile()
    cost = compiled.cost_analysis()
    return float((cost[0] if isinstance(cost, list) else cost)["flops"])


def _alternating_ms(updates: dict, rounds: int, key) -> dict[str, list]:
    """name -> ms per update of each (update, state) in `updates`, BARE_UPDATES updates per
    jitted scan, one round of each in turn, `rounds` times, after one untimed call."""
    import jax

    def looped(update):
        return jax.jit(lambda s, k: jax.lax.scan(update, s, jax.random.split(k, BARE_UPDATES))[0])

    loops = {name: (looped(update), state) for name, (update, state) in updates.items()}
    for loop, state in loops.values():
        jax.block_until_ready(loop(state, key))
    out = {name: [] for name in loops}
    for _ in range(rounds):
        for name, (loop, state) in loops.items():
            start = time.perf_counter()
            jax.block_until_ready(loop(state, key))
            out[name].append((time.perf_counter() - start) / BARE_UPDATES * 1e3)
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", nargs="+", default=list(SIZES), choices=list(SIZES))
    parser.add_argument("--env", default="medium_maze")
    parser.add_argument("--bare", action="store_true", help="time the two updates alone")
    parser.add_argument("--rounds", type=int, default=7, help="--bare: alternating rounds")
    args = parser.parse_args(argv)
    if args.rounds < 1:
        print(f"--rounds must be >= 1, got {args.rounds}", file=sys.stderr)
        return 2
    if args.bare:
        for size in args.sizes:
            ms, flops = bare_update_ms(size, args.rounds, args.env)
            ours, brax = ms["d2c_jax"], ms["brax SAC"]
            for name, values in ms.items():
                median = statistics.median(values)
                rate = flops[name] / median / 1e6  # GFLOP/s at the median
                print(
                    f"{name} {size_label(size)}: median {median:.3f} ms/update, "
                    f"{flops[name] / 1e9:.2f} GFLOP/update (XLA cost analysis), {rate:.0f} GFLOP/s"
                )
            ratio = results.paired_ratio([1 / t for t in ours], [1 / t for t in brax])
            print(f"ours vs brax (updates/s, paired median): {ratio:.2f}x", flush=True)
        return 0
    for size in args.sizes:
        rate = max(epoch_rates(size, args.env))
        print(f"brax SAC {size_label(size)}: {rate:,.1f} env steps/s = updates/s", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
