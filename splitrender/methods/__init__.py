"""Streaming methods: each a server half and a client half (see :mod:`.base`).

Methods are plug-ins found through the ``splitrender.methods`` entry-point group, the
built-in ones included (``pyproject.toml``).  An entry point names a :class:`MethodSpec`
(``package.module:SPEC``) or a module that registers its methods on import.  Another
package adds a method by declaring, in its own ``pyproject.toml``::

    [project.entry-points."splitrender.methods"]
    mymethod = "mypackage.mymethod:SPEC"

A method that fails to load is logged and left out; the others still load.  When
splitrender itself runs from a source tree that was never installed (no entry-point
metadata), the built-in modules are imported directly.
"""

from __future__ import annotations

import importlib
import importlib.metadata
import logging

from .base import (AnyStreamSpec, ClientFeedback, ClientFrame, ClientHalf, DataStreamSpec, DecodedUpdate, MethodConfig,
                   MethodSpec, SceneProducer, ServerContext, ServerHalf, StreamSpec, Update, available_methods, get_method,
                   make_config, methods_for_scene, register_method)

log = logging.getLogger(__name__)

ENTRY_POINT_GROUP = "splitrender.methods"
BUILTIN_MODULES = ("video", "atw", "warp", "sas", "tss", "quads", "probes")
_loaded = False
_seen_entry_points: set[str] = set()


def load_methods(rescan: bool = False) -> None:
    """Register every method of the entry-point group (once; again with ``rescan``)."""
    global _loaded
    if _loaded and not rescan:
        return
    _loaded = True
    builtin_found = set()
    for ep in importlib.metadata.entry_points(group=ENTRY_POINT_GROUP):
        key = f"{ep.name}={ep.value}"
        if ep.value.startswith(__name__ + "."):
            builtin_found.add(ep.name)
        if key in _seen_entry_points:
            continue
        _seen_entry_points.add(key)
        try:
            obj = ep.load()
        except Exception:  # noqa: BLE001 - one broken plug-in must not hide the others
            log.exception("method plug-in %s (%s) failed to load", ep.name, ep.value)
            continue
        if isinstance(obj, MethodSpec):
            register_method(obj)
        elif obj is None or not hasattr(obj, "__name__"):
            log.warning("method plug-in %s (%s) is neither a MethodSpec nor a module", ep.name, ep.value)
    for name in BUILTIN_MODULES:
        if name in builtin_found:
            continue
        try:
            importlib.import_module(f"{__name__}.{name}")
        except ModuleNotFoundError as exc:
            if exc.name != f"{__name__}.{name}":
                raise
            log.debug("method module %s not present", name)


_load_builtin = load_methods  # the name older callers used

__all__ = [
    "AnyStreamSpec", "ClientFeedback", "ClientFrame", "ClientHalf", "DataStreamSpec", "DecodedUpdate", "MethodConfig",
    "MethodSpec", "SceneProducer", "ServerContext", "ServerHalf", "StreamSpec", "Update", "available_methods",
    "get_method", "load_methods", "make_config", "methods_for_scene", "register_method", "ENTRY_POINT_GROUP",
]
