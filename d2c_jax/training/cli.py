"""The `python train.py` command line (ARCHITECTURE.md, "Command line").

    python train.py --env medium_maze [--algo ALGO] [--preset quick] [--seed S] [--seeds N]
        [--total-steps N] [--out DIR] [--resume] [--sac.batch-size 256 ...]
        [--log tensorboard|wandb]
    python train.py --config RUN_DIR/config.json [--seed 3 ...]   # a new run of a saved config
    python train.py --help                       # every flag and config field, by section

Any config field can be overridden as `--<section>.<field-with-dashes> VALUE`
(tuples comma-separated: `--sac.hidden-sizes 256,256`). Bad input exits with status 2
and a one-line message first; no traceback.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import pathlib
import sys
import types
import typing

from d2c_jax import config as config_lib
from d2c_jax import presets
from d2c_jax.training import validation


class UsageError(Exception):
    """Bad command-line input; the message is shown as the first line, then exit 2."""


def _field_types(cls) -> dict[str, object]:
    return typing.get_type_hints(cls)


def _convert(text: str, annotation, name: str):
    """Parses `text` as `annotation`: int, float, bool, str, Literal, tuple or X | None."""
    origin = typing.get_origin(annotation)
    args = typing.get_args(annotation)
    if origin in (typing.Union, types.UnionType):
        if text.lower() == "none" and type(None) in args:
            return None
        (inner,) = [a for a in args if a is not type(None)]
        return _convert(text, inner, name)
    if origin is typing.Literal:
        if text not in args:
            raise UsageError(f"--{name} must be one of {', '.join(map(str, args))}, got {text!r}")
        return text
    if origin is tuple:
        return tuple(_convert(t, args[0], name) for t in text.split(",") if t)
    if annotation is bool:
        if text.lower() not in ("true", "false", "1", "0"):
            raise UsageError(f"--{name} must be true or false, got {text!r}")
        return text.lower() in ("true", "1")
    try:
        return annotation(text)
    except (TypeError, ValueError):
        raise UsageError(f"--{name} must be {annotation.__name__}, got {text!r}") from None


def _has_field(cfg, dotted: str) -> bool:
    head, _, rest = dotted.partition(".")
    if head not in _field_types(type(cfg)):
        return False
    return _has_field(getattr(cfg, head), rest) if rest else True


def apply_override(cfg, dotted: str, text: str, flag: str | None = None):
    """Returns `cfg` with the field at `dotted` (e.g. 'sac.batch_size') set from `text`.

    `flag` is the option as typed, for messages (default: `dotted` with dashes).
    """
    flag = flag or dotted.replace("_", "-")
    head, _, rest = dotted.partition(".")
    hints = _field_types(type(cfg))
    if head not in hints:
        raise UsageError(f"unknown option --{flag}")
    if rest:
        sub = getattr(cfg, head)
        if not dataclasses.is_dataclass(sub):
            raise UsageError(f"unknown option --{flag}")
        return dataclasses.replace(cfg, **{head: apply_override(sub, rest, text, flag)})
    if dataclasses.is_dataclass(getattr(cfg, head)):
        raise UsageError(f"--{flag} is a section; set its fields as --{flag}.<field>")
    return dataclasses.replace(cfg, **{head: _convert(text, hints[head], flag)})


class Parser(argparse.ArgumentParser):
    """argparse with its errors raised as `UsageError` (one line, exit 2), not printed
    with the usage and exited; train.py's and the run commands' parser."""

    def error(self, message):  # argparse's own errors: one line, exit 2 via UsageError
        raise UsageError(message)


def _parser(with_fields: bool = False) -> argparse.ArgumentParser:
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
    docs = config_lib.field_docs(type(cfg))
    hints = _field_types(type(cfg))
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
        if dotted in _CLI_FIELDS:  # shown with its own flag above
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
_CLI_FIELDS = ("env", "preset", "algo", "seed", "num_seeds", "total_steps", "sweep")


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


class Processes(typing.NamedTuple):
    """How this process joins a multi-process job (`jax.distributed`)."""

    coordinator: str | None
    num_processes: int | None
    process_id: int | None


def parse_processes(argv: list[str]) -> Processes | None:
    """The multi-process options, or None for a single-process run.

    Raises:
      UsageError: an incomplete or inconsistent set of options.
    """
    known, _ = _parser().parse_known_args(argv)
    explicit = (known.coordinator, known.num_processes, known.process_id)
    if all(v is None for v in explicit):
        return Processes(None, None, None) if known.distributed else None
    if any(v is None for v in explicit):
        raise UsageError(
            "--coordinator, --num-processes and --process-id go together "
            "(or --distributed alone, with the settings the cluster scheduler sets)"
        )
    if known.num_processes < 1:
        raise UsageError(f"--num-processes must be >= 1, got {known.num_processes}")
    if not 0 <= known.process_id < known.num_processes:
        raise UsageError(
            f"--process-id must be in [0, {known.num_processes - 1}], got {known.process_id}"
        )
    return Processes(*explicit)


def _field_hint(cfg, dotted: str):
    """The type annotation of the field at dotted path `dotted` of `cfg`."""
    head, _, rest = dotted.partition(".")
    if rest:
        return _field_hint(getattr(cfg, head), rest)
    return _field_types(type(cfg))[head]


def parse_sweep(cfg, spec: str):
    """`cfg` with the arm values of one `--sweep FIELD=V1,V2,...` appended to cfg.sweep.

    Raises:
      UsageError: a spec without '=', an unknown or unsweepable field, an empty value,
        or a value of the wrong type.
    """
    from d2c_jax.training import sweep

    name, eq, text = spec.partition("=")
    if not eq or not name or not text:
        raise UsageError(f"--sweep {spec!r} must be FIELD=V1,V2,... (e.g. sac.tau=0.005,0.01)")
    field = name.replace("-", "_")
    if not _has_field(cfg, field) or dataclasses.is_dataclass(config_lib.get_field(cfg, field)):
        raise UsageError(f"--sweep {name}: unknown field; sweepable: {sweep.sweepable_list()}")
    if field not in sweep.SWEEPABLE_FIELDS:
        raise UsageError(
            f"--sweep {name}: cannot be swept (it changes shapes or static counts, or is "
            f"not a hyperparameter); sweepable: {sweep.sweepable_list()}"
        )
    texts = text.split(",")
    if any(not t.strip() for t in texts):
        raise UsageError(f"--sweep {spec!r}: empty value in the list {text!r}")
    hint = _field_hint(cfg, field)
    values = tuple(_convert(t.strip(), hint, f"sweep {name}") for t in texts)
    return dataclasses.replace(cfg, sweep=cfg.sweep + ((field, values),))


def default_out(cfg: config_lib.TrainConfig) -> str:
    """runs/<env>-<preset>-<seed>, with the algo after the env when it is not D2C."""
    algo = "" if cfg.algo == "d2c" else f"-{cfg.algo}"
    return f"runs/{cfg.env}{algo}-{cfg.preset}-{cfg.seed}"


NO_ACCELERATOR_NOTICE = (
    "no GPU found: using the quick preset; --preset paper for the paper's settings"
)


def default_preset(platform: str) -> tuple[str, str | None]:
    """The preset used when none is given, and the line that says why (or None).

    The paper preset (3x512 networks, one update per env step) takes about two days on
    a CPU, so a machine whose default JAX platform is "cpu" gets the quick preset.
    """
    if platform == "cpu":
        return "quick", NO_ACCELERATOR_NOTICE
    return "paper", None


def parse_args(
    argv: list[str], notify: typing.Callable[[str], None] = lambda line: None
) -> tuple[config_lib.TrainConfig, pathlib.Path, bool]:
    """Parses the command line into (config, run directory, resume).

    `notify` receives the line that explains a preset chosen for the user (no --preset),
    once the whole command line is valid: bad input's first line is its error.

    Raises:
      UsageError: for any bad input.
    """
    known, rest = _parser().parse_known_args(argv)
    notices: list[str] = []
    if known.config is not None:
        cfg = saved_config(known.config, known)
    else:
        cfg = _preset_config(known, notices.append)
    for flag, field in (("seed", "seed"), ("seeds", "num_seeds"), ("total_steps", "total_steps")):
        value = getattr(known, flag)
        if value is not None:
            cfg = dataclasses.replace(cfg, **{field: value})
    while rest:
        option = rest.pop(0)
        if not option.startswith("--"):
            raise UsageError(f"unexpected argument {option!r}")
        option, eq, value = option[2:].partition("=")
        if not _has_field(cfg, option.replace("-", "_")):
            raise UsageError(f"unknown option --{option}")
        if not eq:
            if not rest:
                raise UsageError(f"--{option} needs a value")
            value = rest.pop(0)
        cfg = apply_override(cfg, option.replace("-", "_"), value, option)
    for spec in known.sweep:
        cfg = parse_sweep(cfg, spec)
    # Every field's range and the constraints between fields, whatever preset and
    # overrides built the config: nothing invalid reaches the trainer.
    problem = validation.validate(cfg)
    if problem:
        raise UsageError(problem)
    if known.out is not None and not known.out.strip():
        raise UsageError(f"--out must be a directory path, got {known.out!r}")
    out = pathlib.Path(known.out or default_out(cfg))
    for line in notices:
        notify(line)
    return cfg, out, known.resume


def _preset_config(known: argparse.Namespace, notify) -> config_lib.TrainConfig:
    """The config of --env, --preset (default: by the machine, said through `notify`) and
    --algo, before any field override."""
    import envs  # after argparse, so --help stays fast

    if known.env is None:
        raise UsageError("the following arguments are required: --env (or --config)")
    if known.env not in envs.ENV_NAMES:
        raise UsageError(f"unknown env {known.env!r}; valid ids: {', '.join(envs.ENV_NAMES)}")
    preset_name = known.preset
    if preset_name is None:
        import jax

        preset_name, notice = default_preset(jax.default_backend())
        if notice:
            notify(notice)
    try:
        cfg = presets.preset(known.env, preset_name)
        # The algo's fixed settings come before the overrides, so a flag that conflicts
        # with them is seen (and refused by `validation`) rather than overwritten.
        return presets.with_algo(cfg, known.algo or "d2c")
    except ValueError as err:
        raise UsageError(str(err)) from None


def saved_config(path_text: str, known: argparse.Namespace) -> config_lib.TrainConfig:
    """The config in a saved config.json (a run directory names its own), for a new run.

    --env, --preset and --algo may repeat the saved values but not change them: the
    saved config already holds what they would set (the preset's sizes, the algo's
    reward), so a new value would be half applied. Field flags override as usual.

    Raises:
      UsageError: no such file, not JSON, unknown fields, or a conflicting --env,
        --preset or --algo. Values out of range are `validation`'s to refuse.
    """
    path = pathlib.Path(path_text)
    if path.is_dir():
        path = path / "config.json"
    if not path.is_file():
        raise UsageError(f"--config {path_text}: no such file")
    try:
        values = json.loads(path.read_text())
    except (OSError, ValueError) as err:
        reason = "not valid JSON" if isinstance(err, ValueError) else err.strerror
        raise UsageError(f"--config {path}: cannot read it: {reason}") from None
    unknown = config_lib.unknown_fields(config_lib.TrainConfig, values)
    if unknown:
        raise UsageError(f"--config {path}: unknown config fields: {', '.join(unknown)}")
    try:
        cfg = config_lib.from_dict(config_lib.TrainConfig, values)
    except (TypeError, ValueError) as err:
        raise UsageError(f"--config {path}: {err}") from None
    for option in ("env", "preset", "algo"):
        given = getattr(known, option)
        if given is not None and given != getattr(cfg, option):
            raise UsageError(
                f"--{option} {given} conflicts with --config {path}, whose {option} is "
                f"{getattr(cfg, option)}; drop --{option} or start from a preset"
            )
    return cfg


def parse_loggers(argv: list[str]):
    """The logging sinks of --log (`loggers.LoggerOptions`).

    Raises:
      UsageError: an unknown sink, or one whose package is not installed (the message
        gives the pip command).
    """
    from d2c_jax.training import loggers

    known, _ = _parser().parse_known_args(argv)
    names = [n.strip() for text in known.log for n in text.split(",") if n.strip()]
    for name in names:
        if name not in loggers.LOGGER_NAMES:
            raise UsageError(
                f"--log {name}: unknown sink; valid: {', '.join(loggers.LOGGER_NAMES)}"
            )
    names = tuple(dict.fromkeys(names))  # each once, in the order given
    problem = loggers.missing_extra(names)
    if problem:
        raise UsageError(problem)
    if not known.wandb_project.strip():
        raise UsageError("--wandb-project must not be empty")
    return loggers.LoggerOptions(names, known.wandb_project, known.wandb_name)


def wants_help(argv: list[str]) -> bool:
    """True when the command line asks for help (-h or --help before any '--')."""
    for arg in argv:
        if arg == "--":
            return False
        if arg in ("-h", "--help"):
            return True
    return False


def enable_compilation_cache() -> None:
    """Persists compiled programs (default ~/.cache/d2c_jax/xla), so --resume and repeated
    runs of the same config skip the compile. JAX_COMPILATION_CACHE_DIR overrides it."""
    import jax

    if not jax.config.jax_compilation_cache_dir:
        cache = pathlib.Path.home() / ".cache" / "d2c_jax" / "xla"
        jax.config.update("jax_compilation_cache_dir", str(cache))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 1.0)


def main(argv: list[str] | None = None) -> int:
    """Entry point of train.py; returns the exit status."""
    # Imported here: bad flags are refused before JAX, MuJoCo and the package load.
    from d2c_jax.training import loop

    enable_compilation_cache()
    argv = sys.argv[1:] if argv is None else argv
    if wants_help(argv):
        _parser(with_fields=True).print_help()
        return 0
    try:
        processes = parse_processes(argv)
        if processes is not None:  # before anything starts a JAX backend
            from d2c_jax.training import placement

            placement.initialize_processes(*processes)
        log = parse_loggers(argv)
        cfg, out, resume = parse_args(argv, notify=print)
        return loop.train(cfg, out, resume=resume, log=log)
    except UsageError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    except loop.RunError as err:
        print(f"error: {err}", file=sys.stderr)
        return err.status
