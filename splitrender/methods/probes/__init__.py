"""``probes``: light probe streaming (Stengel et al.'s "Streaming DDGI" system, ``papers/light-probe-streaming.txt``).

A GI server traces the scene's DDGI probes once per update for all clients (the
method's scene producer); each client gets only the probes that changed since what it
last received and that can light what it may see, losslessly coded as HEVC, and renders
the scene itself (received once in the session data) with local direct light and the
indirect light of its probe copy.  Modules: :mod:`.server`, :mod:`.client`,
:mod:`.config`; the probes are :mod:`splitrender.render.ddgi`'s, their wire
:mod:`splitrender.gi.stream`.  The scene must have ``gi = "ddgi"`` (``default+gi``).
"""

from __future__ import annotations

from ..base import MethodSpec, register_method
from .config import ProbesConfig

SPEC = register_method(MethodSpec("probes", "splitrender.methods.probes.server:ProbesServer",
                                  "splitrender.methods.probes.client:ProbesClient", ProbesConfig,
                                  "light probe streaming: DDGI probes traced once, streamed losslessly, shaded by the client",
                                  producer="splitrender.methods.probes.server:ProbesProducer", needs_gi=True,
                                  client_draws_scene=True))

__all__ = ["SPEC", "ProbesConfig"]
