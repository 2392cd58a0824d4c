"""Config overrides from the command line: `--<section>.<field> VALUE` and `--sweep`.

A field's text is parsed by the field's type annotation (int, float, bool, str, Literal,
tuple, X | None); anything else is a `UsageError`, whose message is the first line
train.py prints before exiting with status 2.
"""

from __future__ import annotations

import dataclasses
import types
import typing

from d2c_jax import config_io


class UsageError(Exception):
    """Bad command-line input; the message is shown as the first line, then exit 2."""


def field_types(cls) -> dict[str, object]:
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


def has_field(cfg, dotted: str) -> bool:
    head, _, rest = dotted.partition(".")
    if head not in field_types(type(cfg)):
        return False
    return has_field(getattr(cfg, head), rest) if rest else True


def apply_override(cfg, dotted: str, text: str, flag: str | None = None):
    """Returns `cfg` with the field at `dotted` (e.g. 'sac.batch_size') set from `text`.

    `flag` is the option as typed, for messages (default: `dotted` with dashes).
    """
    flag = flag or dotted.replace("_", "-")
    head, _, rest = dotted.partition(".")
    hints = field_types(type(cfg))
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


def _field_hint(cfg, dotted: str):
    """The type annotation of the field at dotted path `dotted` of `cfg`."""
    head, _, rest = dotted.partition(".")
    if rest:
        return _field_hint(getattr(cfg, head), rest)
    return field_types(type(cfg))[head]


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
    if not has_field(cfg, field) or dataclasses.is_dataclass(config_io.get_field(cfg, field)):
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
