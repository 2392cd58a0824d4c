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
import typing

from d2c_jax import config as config_lib
from d2c_jax import config_io, presets
from d2c_jax.training import validation
from d2c_jax.training.options import CLI_FIELDS, Parser, build_parser
from d2c_jax.training.overrides import UsageError, apply_override, has_field, parse_sweep

# Re-exported: `cli.UsageError` and `cli.Parser` are what the run commands and tests
# catch and build; `apply_override`, `parse_sweep` and `CLI_FIELDS` complete the CLI's API.
__all__ = [
    "CLI_FIELDS",
    "Parser",
    "UsageError",
    "apply_override",
    "default_out",
    "default_preset",
    "main",
    "parse_args",
    "parse_sweep",
]


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
    known, _ = build_parser().parse_known_args(argv)
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
    known, rest = build_parser().parse_known_args(argv)
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
        if not has_field(cfg, option.replace("-", "_")):
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
    unknown = config_io.unknown_fields(config_lib.TrainConfig, values)
    if unknown:
        raise UsageError(f"--config {path}: unknown config fields: {', '.join(unknown)}")
    try:
        cfg = config_io.from_dict(config_lib.TrainConfig, values)
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

    known, _ = build_parser().parse_known_args(argv)
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
        build_parser(with_fields=True).print_help()
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
