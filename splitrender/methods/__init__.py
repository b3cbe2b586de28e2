"""Streaming methods: each a server half and a client half (see :mod:`.base`).

Built-in methods register themselves on import; ``_load_builtin`` imports the ones
present, so a method module that fails to import (a missing optional dependency)
does not take the others down.
"""

from __future__ import annotations

import importlib
import logging

from .base import (ClientFeedback, ClientFrame, ClientHalf, DecodedUpdate, MethodConfig, MethodSpec, ServerContext, ServerHalf,
                   StreamSpec, Update, available_methods, get_method, make_config, register_method)

log = logging.getLogger(__name__)

BUILTIN_MODULES = ("video", "atw", "warp", "sas", "tss", "quads", "probes")
_loaded = False


def _load_builtin() -> None:
    global _loaded
    if _loaded:
        return
    _loaded = True
    for name in BUILTIN_MODULES:
        try:
            importlib.import_module(f"{__name__}.{name}")
        except ModuleNotFoundError as exc:
            if exc.name != f"{__name__}.{name}":
                raise
            log.debug("method module %s not present", name)


__all__ = [
    "ClientFeedback", "ClientFrame", "ClientHalf", "DecodedUpdate", "MethodConfig", "MethodSpec", "ServerContext", "ServerHalf",
    "StreamSpec", "Update", "available_methods", "get_method", "make_config", "register_method",
]
