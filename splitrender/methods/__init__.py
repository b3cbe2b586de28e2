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

The registry and the loader live in :mod:`.base` (so that :func:`get_method` there
needs nothing from this package's ``__init__``); this module re-exports them.
"""

from __future__ import annotations

from .base import (BUILTIN_MODULES, ENTRY_POINT_GROUP, AnyStreamSpec, ClientFeedback, ClientFrame, ClientHalf, DataStreamSpec,
                   DecodedUpdate, MethodConfig, MethodSpec, SceneProducer, ServerContext, ServerHalf, StreamSpec, Update,
                   available_methods, get_method, load_methods, make_config, methods_for_scene, register_method)

__all__ = [
    "AnyStreamSpec", "ClientFeedback", "ClientFrame", "ClientHalf", "DataStreamSpec", "DecodedUpdate", "MethodConfig",
    "MethodSpec", "SceneProducer", "ServerContext", "ServerHalf", "StreamSpec", "Update", "available_methods",
    "get_method", "load_methods", "make_config", "methods_for_scene", "register_method", "BUILTIN_MODULES",
    "ENTRY_POINT_GROUP",
]
