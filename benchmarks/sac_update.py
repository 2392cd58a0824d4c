"""The SAC update alone: d2c_jax against the same update in PyTorch, and the CPU roofline.

    python -m benchmarks.sac_update [--sizes paper small] [--write]

One update = the soft TD target, one Adam step on the twin critic, one on the actor, one
on log alpha, and the Polyak target update, on a fixed batch of `medium_maze` features
(obs 6 + goal 2 -> 8 features, action 2). "identical settings" (SB3's schedule): actor and
target every update. "paper": actor and target every 2nd update (Table 2; d2c_jax's
`update_sac_block`). Sizes: paper 3x512 with batch 512; small 2x256 with batch 256.

Roofline: the exact matmul FLOPs of one update (`update_flops`, counted layer by layer;
XLA's own cost analysis of the compiled update is printed beside it), divided by this
machine's rate on one large jitted float32 matmul, measured in the same run. PyTorch runs
the same update with the same layer sizes, Adam, and the critic frozen during the actor
step (a careful PyTorch user's version; SB3's own loop is measured in benchmarks.sb3).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import time

import jax
import jax.numpy as jnp
import numpy as np

import envs
from benchmarks import results
from d2c_jax import config
from d2c_jax.core import networks, sac, types

SIZES = {"paper": ((512, 512, 512), 512), "small": ((256, 256), 256)}
"""Network sizes of every SAC comparison (here, benchmarks.sb3, benchmarks.trainer):
name -> (hidden widths, batch)."""
FEATURES, ACTIONS = 8, 2  # medium_maze: normalize_obs (6) + normalize_goal (2); action (2)
TIMED_UPDATES = {"paper": 40, "small": 200}


def size_label(size: str) -> str:
    """'3x512, 512' for SIZES['paper']: hidden widths, then the batch."""
    hidden, batch = SIZES[size]
    return f"{len(hidden)}x{hidden[0]}, {batch}"


# --- FLOPs -------------------------------------------------------------------------------
def mlp_macs(widths: list[int]) -> int:
    """Multiply-accumulates of one forward pass of one sample through a dense MLP."""
    return sum(a * b for a, b in zip(widths[:-1], widths[1:], strict=True))


def update_flops(hidden: tuple[int, ...], batch: int, actor_every: int) -> float:
    """Matmul FLOPs (2 per MAC) of one SAC update, averaged over the actor cadence.

    Forward = F, weight gradients = F, input gradients = F minus the first layer's (no
    gradient flows into the data). Critic step: actor forward on s' (target action), twin
    target forward, twin forward + both backward passes. Actor step: actor forward, twin
    forward, twin input gradients only (its weights are not trained here; the first
    layer's input gradient is needed for the action), actor forward + both backward.
    """
    actor = [FEATURES, *hidden, 2 * ACTIONS]
    critic = [FEATURES + ACTIONS, *hidden, 1]
    f_actor, f_critic = mlp_macs(actor), mlp_macs(critic)
    first_actor, first_critic = actor[0] * actor[1], critic[0] * critic[1]
    critic_step = f_actor + 2 * f_critic + 2 * (3 * f_critic - first_critic)
    actor_step = f_actor + 2 * f_critic + 2 * f_critic + (2 * f_actor - first_actor)
    return 2.0 * batch * (critic_step + actor_step / actor_every)


# --- this machine's matmul rate --------------------------------------------------------------
def matmul_gflops(n: int = 2048, repeats: int = 10) -> float:
    """GFLOP/s of a jitted (n, n) @ (n, n) float32 matmul (best of `repeats`)."""
    a = jax.random.normal(jax.random.key(0), (n, n), jnp.float32)
    b = jax.random.normal(jax.random.key(1), (n, n), jnp.float32)
    matmul = jax.jit(jnp.matmul)
    matmul(a, b).block_until_ready()
    best = min(_timed(lambda: matmul(a, b).block_until_ready()) for _ in range(repeats))
    return 2 * n**3 / best / 1e9


def _timed(fn) -> float:
    start = time.perf_counter()
    fn()
    return time.perf_counter() - start


# --- d2c_jax -----------------------------------------------------------------------------
def sac_config(size: str, actor_every: int, layer_norm: bool = False) -> config.SACConfig:
    hidden, batch = SIZES[size]
    return dataclasses.replace(
        config.SACConfig(),
        hidden_sizes=hidden,
        batch_size=batch,
        actor_update_every=actor_every,
        target_update_every=actor_every,
        critic_layer_norm=layer_norm,
    )


def random_batch(env, batch: int, n: int, seed: int = 0) -> types.Batch:
    """n stacked random batches of (obs, action, reward, next obs, goal, mask) (n, B, .)."""
    rng = np.random.default_rng(seed)
    lo, hi = env.goal_low, env.goal_high

    def obs():
        xy = rng.uniform(lo, hi, (n, batch, 2))
        rest = rng.uniform(-1, 1, (n, batch, env.obs_dim - 2))
        return jnp.asarray(np.concatenate([xy, rest], -1), jnp.float32)

    return types.Batch(
        obs=obs(),
        action=jnp.asarray(rng.uniform(-1, 1, (n, batch, env.action_dim)), jnp.float32),
        reward=jnp.asarray(rng.uniform(0, 1, (n, batch)), jnp.float32),
        next_obs=obs(),
        goal=jnp.asarray(rng.uniform(lo, hi, (n, batch, 2)), jnp.float32),
        mask=jnp.ones((n, batch), jnp.float32),
    )


def jax_update_rate(
    size: str, actor_every: int, n_updates: int, time_it: bool = True, layer_norm: bool = False
) -> tuple[float, float]:
    """(updates/s, XLA-counted FLOPs per update) of d2c_jax's update, as the trainer runs it.

    `update_sac_block` over a lax.scan of blocks; one fixed batch per block member (the
    sampling is timed in the trainer benchmark, not here). time_it=False: FLOPs only
    (updates/s NaN). layer_norm: LayerNorm in the critics (`sac.critic_layer_norm`).
    """
    env = envs.make("medium_maze")
    cfg = sac_config(size, actor_every, layer_norm)
    nets, opt, hp = networks.make_networks(cfg, env), sac.make_optimizers(), sac.hyperparams(cfg)
    state = sac.init_sac(nets, opt, env, hp, jax.random.key(0))
    block = sac.block_size(cfg)
    batches = random_batch(env, cfg.batch_size, block)
    n_blocks = max(1, n_updates // block)

    def update(state, hp, key):  # the hyperparameters traced, as in the trainer's state
        return sac.update_sac_block(cfg, nets, opt, hp, state, batches, env, key)[0]

    one_block = jax.jit(update)
    cost = one_block.lower(state, hp, jax.random.key(1)).compile().cost_analysis()
    xla_flops = (cost[0] if isinstance(cost, list) else cost).get("flops", float("nan")) / block
    if not time_it:
        return float("nan"), xla_flops

    def run(state, hp, key):
        def body(state, k):
            return update(state, hp, k), None

        return jax.lax.scan(body, state, jax.random.split(key, n_blocks))[0]

    compiled = jax.jit(run).lower(state, hp, jax.random.key(1)).compile()
    jax.block_until_ready(compiled(state, hp, jax.random.key(1)))
    best = min(
        _timed(lambda: jax.block_until_ready(compiled(state, hp, jax.random.key(2))))
        for _ in range(3)
    )
    return n_blocks * block / best, xla_flops


def jax_update_parts(size: str = "paper", repeats: int = 15) -> list[tuple[str, float, float]]:
    """(part, best seconds, FLOPs) of the update's pieces, each jitted alone (identical
    schedule): the critic step, the actor (+ alpha) step, one actor forward, one twin-critic
    forward. Says where the time of `jax_update_rate` goes."""
    env = envs.make("medium_maze")
    cfg = sac_config(size, 1)
    hidden, batch = SIZES[size]
    nets, opt, hp = networks.make_networks(cfg, env), sac.make_optimizers(), sac.hyperparams(cfg)
    state = sac.init_sac(nets, opt, env, hp, jax.random.key(0))
    b = jax.tree.map(lambda x: x[0], random_batch(env, batch, 1))
    feats, next_feats = sac._features(nets, env, b)
    key = jax.random.key(1)
    actor = [FEATURES, *hidden, 2 * ACTIONS]
    critic = [FEATURES + ACTIONS, *hidden, 1]
    flops_actor, flops_critic = 2 * batch * mlp_macs(actor), 2 * batch * mlp_macs(critic)
    total, critic_only = update_flops(hidden, batch, 1), update_flops(hidden, batch, 10**9)
    parts = {
        "critic step": (
            lambda s: sac._critic_step(cfg, nets, opt, hp, s, feats, next_feats, b, key)[0],
            state,
            critic_only,
        ),
        "actor + alpha step": (
            lambda s: sac._actor_step(cfg, nets, opt, hp, s, feats, env.action_dim, key),
            state,
            total - critic_only,
        ),
        "actor forward": (lambda p: nets.actor.apply(p, feats), state.actor_params, flops_actor),
        "twin-critic forward": (
            lambda p: nets.critic.apply(p, feats, b.action),
            state.critic_params,
            2 * flops_critic,
        ),
    }
    out = []
    for name, (fn, arg, flops) in parts.items():
        compiled = jax.jit(fn).lower(arg).compile()
        jax.block_until_ready(compiled(arg))
        best = min(
            _timed(lambda c=compiled, a=arg: jax.block_until_ready(c(a))) for _ in range(repeats)
        )
        out.append((name, best, flops))
    return out


# --- PyTorch -------------------------------------------------------------------------------
def _torch_mlp(hidden, n_in: int, n_out: int):
    """A PyTorch ReLU MLP with hidden widths `hidden`."""
    from torch import nn

    layers, width = [], n_in
    for h in hidden:
        layers += [nn.Linear(width, h), nn.ReLU()]
        width = h
    return nn.Sequential(*layers, nn.Linear(width, n_out))


def _torch_sample(actor, feats):
    """tanh-squashed Gaussian action and its log-density, as `networks` computes them."""
    import torch
    from torch import nn

    mean, raw = actor(feats).chunk(2, -1)
    log_std = -10.0 + 6.0 * (torch.tanh(raw) + 1.0)
    u = mean + log_std.exp() * torch.randn_like(mean)
    log_prob = (-0.5 * ((u - mean) / log_std.exp()) ** 2 - log_std).sum(-1)
    log_prob = log_prob - (2 * (math.log(2) - u - nn.functional.softplus(-2 * u))).sum(-1)
    return torch.tanh(u), log_prob


def _torch_q(nets, feats, action):
    """(2, B) Q-values of the twin critics `nets`."""
    import torch

    x = torch.cat([feats, action], -1)
    return torch.stack([net(x)[..., 0] for net in nets])


def _torch_sac_update(size: str, actor_every: int):
    """update(i): the i-th SAC update in PyTorch on one fixed random batch at SIZES[size]
    (critic every update; actor, alpha and target every `actor_every`)."""
    import torch
    from torch import nn

    hidden, batch = SIZES[size]
    actor = _torch_mlp(hidden, FEATURES, 2 * ACTIONS)
    critics = nn.ModuleList([_torch_mlp(hidden, FEATURES + ACTIONS, 1) for _ in range(2)])
    targets = nn.ModuleList([_torch_mlp(hidden, FEATURES + ACTIONS, 1) for _ in range(2)])
    targets.load_state_dict(critics.state_dict())
    log_alpha = torch.zeros((), requires_grad=True)
    opt_actor = torch.optim.Adam(actor.parameters(), lr=1e-4)
    opt_critic = torch.optim.Adam(critics.parameters(), lr=1e-4)
    opt_alpha = torch.optim.Adam([log_alpha], lr=1e-4)
    gen = torch.Generator().manual_seed(0)
    s, s2 = torch.rand(batch, FEATURES, generator=gen), torch.rand(batch, FEATURES, generator=gen)
    a, r = torch.rand(batch, ACTIONS, generator=gen), torch.rand(batch, generator=gen)

    def step(opt, loss):
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()

    def update(i):
        alpha = log_alpha.exp().detach()
        with torch.no_grad():
            a2, logp2 = _torch_sample(actor, s2)
            y = r + 0.99 * (_torch_q(targets, s2, a2).min(0).values - alpha * logp2)
        step(opt_critic, ((_torch_q(critics, s, a) - y) ** 2).mean())
        if (i + 1) % actor_every:
            return
        critics.requires_grad_(False)
        a_new, logp = _torch_sample(actor, s)
        step(opt_actor, (alpha * logp - _torch_q(critics, s, a_new).min(0).values).mean())
        critics.requires_grad_(True)
        step(opt_alpha, -(log_alpha * (logp.detach() - ACTIONS)).mean())
        with torch.no_grad():
            torch._foreach_lerp_(list(targets.parameters()), list(critics.parameters()), 0.01)

    return update


def torch_update_rate(size: str, actor_every: int, n_updates: int) -> float:
    """Updates/s of the same SAC update written in PyTorch (CPU, all cores)."""
    update = _torch_sac_update(size, actor_every)
    for i in range(max(4, n_updates // 10)):
        update(i)  # warm-up
    start = time.perf_counter()
    for i in range(n_updates):
        update(i)
    return n_updates / (time.perf_counter() - start)


# --- the table -----------------------------------------------------------------------------
def run(sizes, with_torch: bool = True) -> str:
    """Measures every size and schedule; returns the markdown body."""
    peak = matmul_gflops()
    rows = [
        "| size (hidden, batch) | schedule | GFLOP/update (exact; XLA) | tool | updates/s | "
        "GFLOP/s | % of roofline | d2c_jax / tool |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for size in sizes:
        hidden, batch = SIZES[size]
        for schedule, every in (("identical (actor every update)", 1), ("paper (every 2nd)", 2)):
            flops = update_flops(hidden, batch, every)
            ups, xla = jax_update_rate(size, every, TIMED_UPDATES[size])
            lead = f"| {size_label(size)} | {schedule} | {flops / 1e9:.2f}; {xla / 1e9:.2f} |"
            rows.append(
                f"{lead} d2c_jax | {ups:,.1f} | {ups * flops / 1e9:.0f} | "
                f"{100 * ups * flops / 1e9 / peak:.0f}% | |"
            )
            print(rows[-1], flush=True)
            if with_torch:
                tps = torch_update_rate(size, every, TIMED_UPDATES[size])
                rows.append(
                    f"{lead} PyTorch | {tps:,.1f} | {tps * flops / 1e9:.0f} | "
                    f"{100 * tps * flops / 1e9 / peak:.0f}% | {ups / tps:.2f}x |"
                )
                print(rows[-1], flush=True)
    rows += [
        "",
        "Where the time goes (3x512, batch 512, each part jitted alone):",
        "",
        "| part | ms | GFLOP | GFLOP/s | % of roofline |",
        "|---|---|---|---|---|",
    ]
    for name, seconds, flops in jax_update_parts():
        rate = flops / seconds / 1e9
        rows.append(
            f"| {name} | {1e3 * seconds:.1f} | {flops / 1e9:.2f} | {rate:.0f} | "
            f"{100 * rate / peak:.0f}% |"
        )
    versions = f"jax {jax.__version__}"
    if with_torch:
        import torch

        versions += f", torch {torch.__version__} ({torch.get_num_threads()} threads)"
    return "\n".join(
        [
            f"Command: `python -m benchmarks.sac_update --write` ({time.strftime('%Y-%m-%d')}).",
            f"Hardware: {results.hardware()}; {versions}.",
            f"Roofline: a jitted 2048x2048 float32 matmul runs at **{peak:.0f} GFLOP/s** "
            "here (same run); % of roofline = the update's exact matmul FLOPs x updates/s / "
            "that rate.",
            "",
            *rows,
        ]
    )


def layer_norm_cost(sizes: list[str], rounds: int = 2) -> str:
    """Updates/s without and with LayerNorm in the critics, alternating `rounds` times in
    this process (Table 2's schedule: actor and target every 2 updates), and the ratio of
    the best rates."""
    lines = []
    for size in sizes:
        best = {False: 0.0, True: 0.0}
        for _ in range(rounds):
            for layer_norm in (False, True):
                rate, _ = jax_update_rate(size, 2, TIMED_UPDATES[size], layer_norm=layer_norm)
                best[layer_norm] = max(best[layer_norm], rate)
        lines.append(
            f"{size}: {best[False]:.0f} updates/s plain, {best[True]:.0f} with critic "
            f"LayerNorm ({best[True] / best[False]:.2f}x)"
        )
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", nargs="+", default=list(SIZES), choices=list(SIZES))
    parser.add_argument("--no-torch", action="store_true", help="d2c_jax only")
    parser.add_argument("--write", action="store_true", help="update benchmarks/RESULTS.md")
    parser.add_argument(
        "--layer-norm-cost", action="store_true", help="only: the critic LayerNorm's cost"
    )
    args = parser.parse_args(argv)
    if args.layer_norm_cost:
        print(layer_norm_cost(args.sizes))
        return 0
    results.report("SAC update", run(args.sizes, with_torch=not args.no_torch), args.write)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
