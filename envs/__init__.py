"""MJX goal-conditioned environments for d2c_jax.

`ENV_NAMES` lists the environments that exist; `make(name, **overrides)` builds one.
This package never imports `d2c_jax`.
"""

from __future__ import annotations

import contextlib
import importlib
import importlib.util
import io

# mujoco.mjx prints a line when its optional Warp backend is absent; keep imports quiet.
with contextlib.redirect_stdout(io.StringIO()):
    from mujoco import mjx  # noqa: F401

from envs.base import EnvState, GoalEnv, goal_distance

# id -> (module, class name, constructor kwargs), in the order of ARCHITECTURE.md.
_REGISTRY: dict[str, tuple[str, str, dict]] = {
    "complex_maze": ("envs.point_maze", "PointMaze", {"maze": "complex_maze"}),
    "medium_maze": ("envs.point_maze", "PointMaze", {"maze": "medium_maze"}),
    "spiral_maze": ("envs.point_maze", "PointMaze", {"maze": "spiral_maze"}),
    "ant": ("envs.ant", "Ant", {}),
    "sawyer_push": ("envs.sawyer_peg", "SawyerPeg", {"task": "push"}),
    "sawyer_pick_place": ("envs.sawyer_peg", "SawyerPeg", {"task": "pick_place"}),
}

ENV_NAMES: tuple[str, ...] = tuple(
    name for name, (module, _, _) in _REGISTRY.items() if importlib.util.find_spec(module)
)


def _env_class(name: str) -> tuple[type[GoalEnv], dict]:
    """The class of environment `name` and its constructor kwargs (nothing is built).

    Raises:
      ValueError: for an unknown id; the message lists the valid ids.
    """
    if name not in ENV_NAMES:
        raise ValueError(f"unknown env {name!r}; valid ids: {', '.join(ENV_NAMES)}")
    module, cls_name, kwargs = _REGISTRY[name]
    return getattr(importlib.import_module(module), cls_name), kwargs


def make(name: str, **overrides) -> GoalEnv:
    """Builds environment `name`; keyword `overrides` go to its constructor.

    Raises:
      ValueError: for an unknown id; the message lists the valid ids.
    """
    cls, kwargs = _env_class(name)
    return cls(**{**kwargs, **overrides})


def horizon(name: str) -> int:
    """Episode length H of environment `name` in env steps (`env.horizon`), read from its
    class: no MJX model is built.

    Raises:
      ValueError: for an unknown id; the message lists the valid ids.
    """
    return _env_class(name)[0].horizon


def to_brax(env: GoalEnv):
    """`env` as a `brax.envs.Env` whose obs is the agent's goal-conditioned input and whose
    reward is the sparse success reward (`envs.brax_adapter`, which says what is where).

    Imported on first call: brax's import costs about a second, which `import envs` need not.
    """
    from envs.brax_adapter import to_brax as adapt

    return adapt(env)


__all__ = ["ENV_NAMES", "EnvState", "GoalEnv", "goal_distance", "horizon", "make", "to_brax"]
