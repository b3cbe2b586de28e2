"""``probes`` client half (paper section 3.5): renders the scene itself, lit by its copy of the probes.

The scene arrives once in the session data; each update brings the moving objects' transforms
and light intensities of its frame, and the probes the server selected (the ``index``
stream names their slots in the two lossless pictures).  The client scatters the
decoded blocks into its probe textures, rebuilds the guard bands, and draws primary
visibility, direct light with shadows and the probes' indirect light with the same
shader as the ground truth.  The client draws from its first update on, before any probe has
arrived (direct light only; the indirect light fills in as probes arrive).  An update
whose pictures are missing (lost, or undecodable until the next I-frame) still moves the
objects and sets the lights; malformed data raises a named error and the last good state
stays on screen.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ...gi.ddgi import ProbeCopy
from ...gi.stream import ProbeStreamError, color_from_frame, decode_index_list, decode_irradiance, visibility_from_frame
from ...scene.model import Schedule
from ...scene.pose import Pose
from ...scene.wire import scene_from_data
from ..base import ClientFrame, ClientHalf, DecodedUpdate
from .server import META_VERSION


class ProbesClient(ClientHalf):
    """Light probe streaming, client half."""

    def __init__(self, *a: Any, **kw: Any) -> None:
        super().__init__(*a, **kw)
        sd = self.session_data
        if not isinstance(sd, dict) or sd.get("v") != META_VERSION:
            raise ProbeStreamError(f"probes session data: expected a map with v={META_VERSION}")
        self.scene, self._moving = scene_from_data(sd.get("scene"))
        try:
            origin = np.asarray(sd["origin"], np.float64).reshape(3)
            spacing = np.asarray(sd["spacing"], np.float64).reshape(3)
            counts = tuple(int(c) for c in sd["counts"])
            bias = float(sd["bias"])
            self.vis_lossy = sd.get("vis_lossy", False) is True
        except (KeyError, TypeError, ValueError) as exc:
            raise ProbeStreamError(f"probes session data: missing or malformed grid ({exc})") from None
        if len(counts) != 3 or not all(2 <= c <= 64 for c in counts) or not (np.isfinite(origin).all() and
                                                                             (spacing > 0).all() and np.isfinite(bias)):
            raise ProbeStreamError("probes session data: the probe grid is out of range")
        from ...render.renderer import Renderer

        self.renderer = Renderer(self.gl)
        self.probes = ProbeCopy(self.gl, origin, spacing, counts, bias)   # type: ignore[arg-type]
        self.renderer.gi_sources[id(self.scene)] = self.probes
        self.count = self.probes.count
        self.has_content = False

    def apply(self, update: DecodedUpdate) -> None:
        meta = update.meta
        if not isinstance(meta, dict) or meta.get("v") != META_VERSION:
            raise ProbeStreamError(f"probes metadata: expected a map with v={META_VERSION}")
        xf = meta.get("xf")
        moving = [o for o in self.scene.objects if o.object_id in self._moving]
        n_obj = len(moving)
        if not isinstance(xf, np.ndarray) or xf.shape != (n_obj, 4, 4) or not np.isfinite(xf).all():
            raise ProbeStreamError(f"probes metadata: 'xf' must be finite ({n_obj}, 4, 4), got {getattr(xf, 'shape', type(xf).__name__)}")
        lights = meta.get("lights")
        sun = meta.get("sun")
        if (not isinstance(lights, list) or len(lights) != len(self.scene.point_lights)
                or not all(isinstance(v, (int, float)) and 0 <= v < 1e6 for v in [*lights, sun])):
            raise ProbeStreamError("probes metadata: 'sun' and 'lights' must be intensities in [0, 1e6)")
        probes = None
        sent = {"color", "vis"} & set(update.planes)
        if not ({"color", "vis", "index"} & set(update.missing)) and sent:
            if "index" not in update.data:
                raise ProbeStreamError("probe update: pictures without an index list")
            ids = decode_index_list(update.data["index"], self.count)
            irr = mom = None
            if "color" in sent:
                irr = decode_irradiance(color_from_frame(update.planes["color"], self.count)[ids])
            if "vis" in sent:
                mom = visibility_from_frame(update.planes["vis"], self.count)[ids].astype(np.float32)
                if self.vis_lossy:         # the ablation's damaged bytes: keep what is a distance, zero the rest
                    mom = np.where(np.isfinite(mom) & (mom >= 0), np.minimum(mom, 1e4), 0.0).astype(np.float32)
                if not np.isfinite(mom).all():
                    raise ProbeStreamError("probes visibility: non-finite distance moments")
            probes = (ids, irr, mom)
        # everything checked: take it
        for o, m in zip(moving, xf):
            self._moving[o.object_id].m = np.asarray(m, np.float64) @ np.linalg.inv(o.transform)  # model = holder.m @ transform
        if self.scene.sun is not None:
            self.scene.sun.intensity = Schedule.constant(float(sun))  # type: ignore[arg-type]
        for pl, v in zip(self.scene.point_lights, lights):
            pl.intensity = Schedule.constant(float(v))
        if probes is not None:
            self.probes.scatter(*probes)
        self.has_content = True       # the scene is here: draw it, the indirect light filling in as probes arrive

    def render(self, pose: Pose, t_s: float) -> ClientFrame:
        out = self.renderer.render(self.scene, t_s, pose, self.intrinsics)
        return ClientFrame(out.color, None, {"cli_probes": float(self.probes.received.sum())})


__all__ = ["ProbesClient"]
