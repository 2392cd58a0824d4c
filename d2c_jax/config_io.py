"""Config dataclasses as config.json dicts and dotted field paths: reading a saved
config (`from_dict`, with `_upgrade` for older runs), spotting fields a dict has that the
config lacks (`unknown_fields`), dotted access (`get_field`, `replace_field`: "sac.tau")
and the fields' one-line docs for `--help` (`field_docs`).

The dataclasses themselves live in `d2c_jax.config`, which re-exports these names.
"""

from __future__ import annotations

import dataclasses
import typing

from d2c_jax.config import ENV_SETTINGS, TrainConfig, iteration_steps


def from_dict(cls, values: dict):
    """A (nested, frozen) config dataclass from its config.json dict; lists become tuples.

    Missing fields take their defaults; a TrainConfig dict from before
    `curriculum.goal_noise` existed is first read as that run ran (`_upgrade`).
    """
    if cls is TrainConfig:
        values = _upgrade(values)
    hints = typing.get_type_hints(cls)
    kwargs = {}
    for field in dataclasses.fields(cls):
        if field.name not in values:
            continue
        value, hint = values[field.name], hints[field.name]
        if dataclasses.is_dataclass(hint):
            value = from_dict(hint, value)
        elif field.name == "sweep" and cls is TrainConfig:
            value = tuple((name, tuple(values)) for name, values in value)
        elif isinstance(value, list):
            value = tuple(value)
        kwargs[field.name] = value
    return cls(**kwargs)


def replace_field(cfg, dotted: str, value):
    """`cfg` with the field at dotted path `dotted` (e.g. "sac.tau") set to `value`."""
    head, _, rest = dotted.partition(".")
    if rest:
        value = replace_field(getattr(cfg, head), rest, value)
    return dataclasses.replace(cfg, **{head: value})


def get_field(cfg, dotted: str):
    """The value of the field at dotted path `dotted` of `cfg`."""
    for name in dotted.split("."):
        cfg = getattr(cfg, name)
    return cfg


def _upgrade(values: dict) -> dict:
    """A TrainConfig dict in today's terms. One without `curriculum.goal_noise` was
    written before that field existed, when the curriculum goals were noised by
    `classifier.eps` and `checkpoint_every` counted iterations, not env steps."""
    curriculum = values.get("curriculum", {})
    if "goal_noise" in curriculum:
        return values
    values = dict(values)
    if "eps" in values.get("classifier", {}):
        values["curriculum"] = {**curriculum, "goal_noise": values["classifier"]["eps"]}
    env = values.get("env", TrainConfig.env)
    if "checkpoint_every" in values and env in ENV_SETTINGS:
        num_envs = values.get("num_envs", TrainConfig.num_envs)
        values["checkpoint_every"] = iteration_steps(env, num_envs, values["checkpoint_every"])
    return values


def unknown_fields(cls, values, prefix: str = "") -> list[str]:
    """Dotted names in a config.json-style dict `values` that config dataclass `cls` lacks,
    or that give a section (a nested config) as something other than an object.

    Example: {"sac": {"batchsize": 1}} -> ["sac.batchsize"].
    """
    if not isinstance(values, dict):
        return [prefix.rstrip(".") or "(top level: not an object)"]
    hints = typing.get_type_hints(cls)
    problems = []
    for name, value in values.items():
        if name not in hints:
            problems.append(prefix + name)
        elif dataclasses.is_dataclass(hints[name]):
            problems += unknown_fields(hints[name], value, prefix + name + ".")
    return problems


def field_docs(cls) -> dict[str, str]:
    """The docstring of each field of config dataclass `cls`, on one line, read from the
    source: every field here is followed by a string literal."""
    import ast
    import inspect
    import textwrap

    tree = ast.parse(textwrap.dedent(inspect.getsource(cls)))
    body = tree.body[0].body
    docs = {}
    for node, following in zip(body, body[1:], strict=False):
        if (
            isinstance(node, ast.AnnAssign)
            and isinstance(node.target, ast.Name)
            and isinstance(following, ast.Expr)
            and isinstance(following.value, ast.Constant)
            and isinstance(following.value.value, str)
        ):
            docs[node.target.id] = " ".join(following.value.value.split())
    return docs
