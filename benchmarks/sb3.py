"""Stable-Baselines3 SAC + HER training throughput (the reference users would pick today).

    python -m benchmarks.sb3 [--sizes paper small]

SB3 SAC with `HerReplayBuffer` (future strategy, 4 sampled goals) on gymnasium-robotics
`PointMaze_Medium-v3`, one gradient step per env step (train_freq 1, gradient_steps 1),
actor and target every step (SB3's schedule), Adam 1e-4, automatic entropy. Sizes: paper
3x512 with batch 512, small 2x256 with batch 256. Steady state: env steps/s between the
first `warmup` env steps after learning starts and the end. Needs the `bench` extra
(`pip install -e '.[bench]'`: stable-baselines3, gymnasium-robotics, torch).
"""

from __future__ import annotations

import argparse
import time

from benchmarks.sac_update import SIZES

TIMED_STEPS = {"paper": 300, "small": 1500}
LEARNING_STARTS = 1000
WARMUP = 50


def sb3_env_steps_per_s(size: str, timed_steps: int | None = None) -> float:
    """Steady-state env steps/s of SB3 SAC + HER at `size` on PointMaze_Medium-v3."""
    try:
        import gymnasium as gym
        import gymnasium_robotics
        from stable_baselines3 import SAC, HerReplayBuffer
        from stable_baselines3.common.callbacks import BaseCallback
    except ImportError as err:
        hint = "benchmarks.sb3 needs the bench extra: pip install -e '.[bench]'"
        raise SystemExit(f"{hint} ({err})") from None

    gym.register_envs(gymnasium_robotics)
    net_arch, batch = SIZES[size]
    timed = timed_steps or TIMED_STEPS[size]
    start_at = LEARNING_STARTS + WARMUP

    class Clock(BaseCallback):
        """Records the wall-clock at env step `start_at` and at the end."""

        def __init__(self):
            super().__init__()
            self.start = None

        def _on_step(self) -> bool:
            if self.num_timesteps == start_at:
                self.start = time.perf_counter()
            return True

    env = gym.make("PointMaze_Medium-v3")
    model = SAC(
        "MultiInputPolicy",
        env,
        replay_buffer_class=HerReplayBuffer,
        replay_buffer_kwargs=dict(n_sampled_goal=4, goal_selection_strategy="future"),
        policy_kwargs=dict(net_arch=list(net_arch)),
        batch_size=batch,
        learning_rate=1e-4,
        buffer_size=1_000_000,
        learning_starts=LEARNING_STARTS,
        train_freq=1,
        gradient_steps=1,
        tau=0.01,
        gamma=0.99,
        device="cpu",
        seed=0,
        verbose=0,
    )
    clock = Clock()
    model.learn(total_timesteps=start_at + timed, callback=clock)
    elapsed = time.perf_counter() - clock.start
    return timed / elapsed


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", nargs="+", default=list(SIZES), choices=list(SIZES))
    args = parser.parse_args(argv)
    for size in args.sizes:
        print(f"SB3 SAC+HER {size}: {sb3_env_steps_per_s(size):,.1f} env steps/s", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
