"""The `python train.py` command line (ARCHITECTURE.md, "Command line").

    python train.py --env medium_maze [--preset quick] [--seed S] [--seeds N]
        [--total-steps N] [--out DIR] [--resume] [--sac.batch-size 256 ...]

Any config field can be overridden as `--<section>.<field-with-dashes> VALUE`
(tuples comma-separated: `--sac.hidden-sizes 256,256`). Bad input exits with status 2
and a one-line message first; no traceback.
"""

from __future__ import annotations

import argparse
import dataclasses
import pathlib
import sys
import types
import typing

from d2c_jax import config as config_lib
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


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # argparse's own errors: one line, exit 2 via UsageError
        raise UsageError(message)


def _parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="train.py",
        description="Train D2C. Any config field: --<section>.<field> VALUE (see config.py).",
        add_help=True,
    )
    parser.add_argument("--env", required=True, help="environment id")
    parser.add_argument(
        "--preset",
        default=None,
        help="paper | quick | tiny (default: paper with an accelerator, quick without)",
    )
    parser.add_argument("--seed", type=int, default=None, help="first seed S")
    parser.add_argument("--seeds", type=int, default=None, help="N seeds S..S+N-1, vmapped")
    parser.add_argument("--total-steps", type=int, default=None, help="env steps to train")
    parser.add_argument("--out", default=None, help="run directory")
    parser.add_argument("--resume", action="store_true", help="continue the run in --out")
    return parser


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

    `notify` receives the line that explains a preset chosen for the user (no --preset).

    Raises:
      UsageError: for any bad input.
    """
    known, rest = _parser().parse_known_args(argv)
    import envs  # after argparse, so --help stays fast

    if known.env not in envs.ENV_NAMES:
        raise UsageError(f"unknown env {known.env!r}; valid ids: {', '.join(envs.ENV_NAMES)}")
    preset_name = known.preset
    if preset_name is None:
        import jax

        preset_name, notice = default_preset(jax.default_backend())
        if notice:
            notify(notice)
    try:
        cfg = config_lib.preset(known.env, preset_name)
    except ValueError as err:
        raise UsageError(str(err)) from None
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
    # Every field's range and the constraints between fields, whatever preset and
    # overrides built the config: nothing invalid reaches the trainer.
    problem = validation.validate(cfg)
    if problem:
        raise UsageError(problem)
    if known.out is not None and not known.out.strip():
        raise UsageError(f"--out must be a directory path, got {known.out!r}")
    out = pathlib.Path(known.out or f"runs/{cfg.env}-{cfg.preset}-{cfg.seed}")
    return cfg, out, known.resume


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
    try:
        cfg, out, resume = parse_args(sys.argv[1:] if argv is None else argv, notify=print)
        return loop.train(cfg, out, resume=resume)
    except UsageError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    except loop.RunError as err:
        print(f"error: {err}", file=sys.stderr)
        return err.status
