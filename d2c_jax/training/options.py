"""The options of `python train.py` and their --help (README.md, "Command line").

The named options are parsed here; config fields are parsed by `overrides.apply_override`,
and listed here only for --help, by section, with their one-line docs and defaults.
"""

from __future__ import annotations

import argparse
import dataclasses
import types
import typing

from d2c_jax import config as config_lib
from d2c_jax import config_io
from d2c_jax.training import validation
from d2c_jax.training.overrides import UsageError, field_types


class Parser(argparse.ArgumentParser):
    """argparse with its errors raised as `UsageError` (one line, exit 2), not printed
    with the usage and exited; train.py's and the run commands' parser."""

    def error(self, message):  # argparse's own errors: one line, exit 2 via UsageError
        raise UsageError(message)


def build_parser(with_fields: bool = False) -> argparse.ArgumentParser:
    """The options of train.py; `with_fields` adds every config field (for --help only:
    the fields are parsed by `apply_override`, which knows their types)."""
    parser = Parser(
        prog="train.py",
        usage="%(prog)s (--env ENV | --config RUN_DIR/config.json) [options] "
        "[--<section>.<field> VALUE ...]",
        description="Train D2C or a baseline (README.md). Any config field can be set as "
        "--<section>.<field> VALUE; tuples comma-separated.",
        epilog="Defaults of the config fields are TrainConfig()'s (medium_maze, paper "
        "preset); the presets and --algo change some of them. Bad input exits with status 2.",
        add_help=True,
    )
    parser.add_argument("--env", default=None, help="environment id: " + ", ".join(_env_ids()))
    parser.add_argument(
        "--config",
        default=None,
        metavar="RUN_DIR/config.json",
        help="start a new run from a saved config (its env, preset and algo; flags given "
        "here override its fields)",
    )
    parser.add_argument(
        "--preset",
        default=None,
        metavar="NAME",
        help="paper | quick | tiny (default: paper with an accelerator, quick without)",
    )
    parser.add_argument(
        "--algo",
        default=None,
        metavar="NAME",
        help=f"{' | '.join(config_lib.ALGO_NAMES)}: D2C or a baseline on the same SAC, HER "
        "and pool (default d2c; docs/BASELINES.md)",
    )
    parser.add_argument("--seed", type=int, default=None, metavar="S", help="first seed S (0)")
    parser.add_argument(
        "--seeds", type=int, default=None, metavar="N", help="N seeds S..S+N-1, vmapped (1)"
    )
    parser.add_argument(
        "--total-steps", type=int, default=None, metavar="N", help="env steps to train"
    )
    parser.add_argument(
        "--out", default=None, metavar="DIR", help="run directory (runs/<env>-<preset>-<seed>)"
    )
    parser.add_argument("--resume", action="store_true", help="continue the run in --out")
    parser.add_argument(
        "--sweep",
        action="append",
        default=[],
        metavar="FIELD=V1,V2,...",
        help="sweep a hyperparameter (repeatable): every combination of the values, each "
        "with seeds S..S+N-1, runs as one program; e.g. classifier.diversity-weight=0,1",
    )
    _add_process_options(parser)
    _add_logging_options(parser)
    if with_fields:
        _add_field_groups(parser, config_lib.TrainConfig())
    return parser


def _add_process_options(parser: argparse.ArgumentParser) -> None:
    """The options of a multi-process job (`parse_processes`)."""
    hosts = parser.add_argument_group(
        "several processes (hosts)", "each process runs its share of the runs (README, Scaling out)"
    )
    hosts.add_argument("--coordinator", default=None, help="HOST:PORT of process 0")
    hosts.add_argument("--num-processes", type=int, default=None, help="processes in the job")
    hosts.add_argument("--process-id", type=int, default=None, help="this process, 0..P-1")
    hosts.add_argument(
        "--distributed",
        action="store_true",
        help="join a multi-process job whose settings the cluster scheduler sets (SLURM, ...)",
    )


def _add_logging_options(parser: argparse.ArgumentParser) -> None:
    """The logging sinks beside metrics.jsonl (`parse_loggers`)."""
    logs = parser.add_argument_group(
        "logging", "metrics.jsonl is always written; these add a sink beside it (extra: [log])"
    )
    logs.add_argument(
        "--log",
        action="append",
        default=[],
        metavar="SINK",
        help="tensorboard (event files in RUN_DIR/tensorboard) or wandb (offline unless "
        "WANDB_MODE=online; files in RUN_DIR/wandb); repeatable or comma-separated",
    )
    logs.add_argument("--wandb-project", default="d2c_jax", help="W&B project (default d2c_jax)")
    logs.add_argument(
        "--wandb-name", default=None, help="W&B run name (default: the run directory's name)"
    )


def _env_ids() -> tuple[str, ...]:
    """The env ids without importing MJX (config lists the same ids as envs)."""
    return tuple(config_lib.ENV_SETTINGS)


def _add_field_groups(parser: argparse.ArgumentParser, cfg, prefix: str = "") -> None:
    """One help group per config section, one entry per field: its doc and default."""
    docs = config_io.field_docs(type(cfg))
    hints = field_types(type(cfg))
    title = prefix.rstrip(".") or "run"
    group = parser.add_argument_group(
        f"config: {title}", (type(cfg).__doc__ or "").strip().splitlines()[0]
    )
    sections = []
    for field in dataclasses.fields(cfg):
        value = getattr(cfg, field.name)
        if dataclasses.is_dataclass(value):
            sections.append((value, prefix + field.name + "."))
            continue
        dotted = prefix + field.name
        if dotted in CLI_FIELDS:  # shown with its own flag above
            continue
        flag = validation.flag_name(dotted)
        default = validation.show_value(value)
        group.add_argument(
            flag,
            metavar=_metavar(hints[field.name]),
            help=f"{docs.get(field.name, '')} (default: {default})".replace("%", "%%"),
        )
    for section, section_prefix in sections:
        _add_field_groups(parser, section, section_prefix)


# Fields with their own option in `_parser` (not listed again among the config fields).
CLI_FIELDS = ("env", "preset", "algo", "seed", "num_seeds", "total_steps", "sweep")


def _metavar(annotation) -> str:
    """How a field's value is written: INT, FLOAT, BOOL, TEXT, a|b|c, or INT,INT,..."""
    origin, args = typing.get_origin(annotation), typing.get_args(annotation)
    if origin in (typing.Union, types.UnionType):
        (inner,) = [a for a in args if a is not type(None)]
        return _metavar(inner) + "|none"
    if origin is typing.Literal:
        return "|".join(map(str, args))
    if origin is tuple:
        return f"{_metavar(args[0])},..."
    return {bool: "BOOL", int: "INT", float: "FLOAT"}.get(annotation, "TEXT")
