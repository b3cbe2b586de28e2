"""Checking configuration values read from TOML or the command line against dataclass field types.

Shared by the run config (:mod:`splitrender.sim.config`) and every method's config
(:func:`splitrender.methods.base.make_config`); it sits low in the package (it imports
only :mod:`splitrender.errors`) so neither reaches sideways for it.
"""

from __future__ import annotations

import types
import typing
from typing import Any

from .errors import ConfigError

__all__ = ["coerce_value"]


def coerce_value(owner: str, key: str, hint: Any, v: Any) -> Any:
    """``v`` (a TOML or CLI value) checked against the type hint of field ``owner.key``.

    Ints are accepted as floats (and become floats), lists become tuples for a tuple
    field, ``Literal`` values must be one of the listed ones, a ``Union`` takes the first
    member that fits; a hint it does not know (or ``None``) passes ``v`` through.
    Raises :class:`~splitrender.errors.ConfigError` naming ``owner.key`` and the value.
    """
    if hint is None:
        return v
    origin = typing.get_origin(hint)
    args = typing.get_args(hint)
    if origin in (typing.Union, types.UnionType):
        if v is None and type(None) in args:
            return None
        for a in args:
            if a is type(None):
                continue
            try:
                return coerce_value(owner, key, a, v)
            except ConfigError:
                pass  # try the next member
        raise ConfigError(f"{owner}.{key}: {v!r} does not fit {hint}")
    if origin is typing.Literal:
        if v not in args:
            raise ConfigError(f"{owner}.{key}: {v!r} is not one of {list(args)}")
        return v
    if origin in (tuple, list):
        if not isinstance(v, (list, tuple)):
            raise ConfigError(f"{owner}.{key}: expected a list, got {type(v).__name__} {v!r}")
        return tuple(v) if origin is tuple else list(v)
    if hint is float:
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise ConfigError(f"{owner}.{key}: expected a number, got {type(v).__name__} {v!r}")
        return float(v)
    if hint is int:
        if isinstance(v, bool) or not isinstance(v, int):
            raise ConfigError(f"{owner}.{key}: expected an integer, got {type(v).__name__} {v!r}")
        return v
    if hint is bool:
        if not isinstance(v, bool):
            raise ConfigError(f"{owner}.{key}: expected true/false, got {type(v).__name__} {v!r}")
        return v
    if hint is str:
        if not isinstance(v, str):
            raise ConfigError(f"{owner}.{key}: expected a string, got {type(v).__name__} {v!r}")
        return v
    return v
