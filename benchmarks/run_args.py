"""The command line that the run probes share: a run directory, a seed, a count of episodes.

`benchmarks.actor_probe`, `critic_probe`, `reward_probe` and `visit_map` each read one
seed of a trained run; this module owns the arguments they have in common and their
checks, so that every probe refuses bad input the same way (`runs.RunError`, exit 2).
"""

from __future__ import annotations

import argparse


def probe_parser(doc: str, episodes: int | None = None):
    """An `ArgumentParser` described by `doc`'s first line, with the positional run
    directory `run`, `--seed-index` and, where `episodes` is given, `--episodes` with
    that default (checked by `check_episodes`)."""
    parser = argparse.ArgumentParser(description=doc.splitlines()[0])
    parser.add_argument("run")
    parser.add_argument("--seed-index", type=int, default=0)
    if episodes is not None:
        parser.add_argument("--episodes", type=int, default=episodes)
    return parser


def check_episodes(episodes: int) -> None:
    """Raise `runs.RunError` (exit 2) unless `episodes` >= 1."""
    from d2c_jax.training import runs

    if episodes < 1:
        raise runs.RunError(f"--episodes must be >= 1, got {episodes}", 2)
