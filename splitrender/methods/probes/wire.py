"""``probes``' session data and per-frame metadata as the client half checks them.

Session data: ``v`` (:data:`META_VERSION`), ``scene`` (:mod:`splitrender.scene.wire`),
the probe grid ``origin`` (metres), ``spacing`` (metres, > 0), ``counts`` (three, each
2..64, their product at most the client's ``ClientLimits.max_probes``), ``bias``
(metres) and ``vis_lossy`` (the ablation's lossy visibility).  Per frame: ``v``, ``t_gi``
(the probes' update time, s), ``xf`` float32 (n_moving, 4, 4) the moving objects'
transforms in scene order (affine, entries within +-1e6, invertible), ``sun`` and
``lights`` (one per point light) intensities in [0, 1e6).  The probe pictures and the
``index`` stream are checked by :mod:`splitrender.gi.stream`.

Errors are :class:`~splitrender.gi.stream.ProbeStreamError` naming the field
(``probes metadata: xf[0]: singular transform (|det| 0 < 1e-12)``); the scene's are
:class:`~splitrender.scene.wire.SceneWireError`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ...gi.stream import ProbeStreamError
from ...limits import DEFAULT_CLIENT_LIMITS, ClientLimits
from ...protocol.schema import Bool, Float, Int, Map, Opt, Schema, Seq, Transforms, Version

META_VERSION = 2
MAX_COUNT = 64
"""Most probes along one axis of the grid."""
MAX_COORD_M = 1e6
MAX_INTENSITY = 1e6

SESSION = Schema("probes session data", ProbeStreamError, Map({
    "v": Version(META_VERSION),
    "counts": Seq(Int(2, MAX_COUNT), 3),
    "origin": Seq(Float(-MAX_COORD_M, MAX_COORD_M), 3),
    "spacing": Seq(Float(0.0, MAX_COORD_M, lo_open=True), 3),
    "bias": Float(-MAX_COORD_M, MAX_COORD_M),
    "vis_lossy": Opt(Bool(), False),
}))
"""The probe grid of the session data (the scene is checked by :func:`~splitrender.scene.wire.scene_from_data`)."""

META = Schema("probes metadata", ProbeStreamError, Map({
    "v": Version(META_VERSION),
    "xf": Transforms("n_moving"),
    "sun": Float(0.0, MAX_INTENSITY, hi_open=True),
    "lights": Seq(Float(0.0, MAX_INTENSITY, hi_open=True), "n_lights"),
}))
"""One frame's metadata: the moving objects' transforms and the light intensities."""


@dataclass(frozen=True)
class Grid:
    """The session's probe grid: ``origin`` and ``spacing`` (3,) metres, ``counts`` per axis, ``bias`` metres."""

    origin: np.ndarray
    spacing: np.ndarray
    counts: tuple[int, int, int]
    bias: float
    vis_lossy: bool


def parse_grid(sd: Any, limits: ClientLimits = DEFAULT_CLIENT_LIMITS) -> Grid:
    """The probe grid of the session data; raises :class:`ProbeStreamError` naming the field, also when the grid
    has more probes than ``limits.max_probes`` (before anything is allocated for it)."""
    d = SESSION.parse(sd)
    cx, cy, cz = d["counts"]
    if cx * cy * cz > limits.max_probes:
        raise SESSION.error_at("counts", f"{cx}x{cy}x{cz} = {cx * cy * cz} probes, over this client's limit of "
                                         f"{limits.max_probes} (ClientLimits.max_probes)")
    return Grid(np.array(d["origin"], np.float64), np.array(d["spacing"], np.float64), (cx, cy, cz), d["bias"],
                d["vis_lossy"])


@dataclass(frozen=True)
class FrameMeta:
    """One frame's validated metadata: ``xf`` (n_moving, 4, 4) float32, ``sun`` and ``lights`` intensities."""

    xf: np.ndarray
    sun: float
    lights: list[float]


def parse_frame_meta(meta: Any, n_moving: int, n_lights: int) -> FrameMeta:
    """Validate one frame's metadata against the scene (``n_moving`` moving objects, ``n_lights`` point lights)."""
    m = META.parse(meta, {"n_moving": n_moving, "n_lights": n_lights})
    return FrameMeta(m["xf"], m["sun"], m["lights"])
