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
stays on screen.  The session data and metadata are checked by :mod:`.wire` and
:mod:`splitrender.scene.wire` (against this client's ``limits``) before anything is
allocated or applied.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ...render.ddgi import ProbeCopy
from ...gi.stream import ProbeStreamError, color_from_frame, decode_index_list, decode_irradiance, visibility_from_frame
from ...scene.model import Schedule
from ...scene.pose import Pose
from ...scene.wire import scene_from_data
from ..base import ClientFrame, ClientHalf, DecodedUpdate
from .wire import parse_frame_meta, parse_grid


class ProbesClient(ClientHalf):
    """Light probe streaming, client half."""

    def __init__(self, *a: Any, **kw: Any) -> None:
        super().__init__(*a, **kw)
        sd = self.session_data
        grid = parse_grid(sd, self.limits)              # the grid first: a huge one is refused before the scene is read
        self.scene, self._moving = scene_from_data(sd.get("scene"), self.limits)
        self.vis_lossy = grid.vis_lossy
        from ...render.renderer import Renderer

        self.renderer = Renderer(self.gl)
        self.probes = ProbeCopy(self.gl, grid.origin, grid.spacing, grid.counts, grid.bias)
        self.renderer.gi_sources[id(self.scene)] = self.probes
        self.count = self.probes.count
        self.has_content = False

    def apply(self, update: DecodedUpdate) -> None:
        moving = [o for o in self.scene.objects if o.object_id in self._moving]
        m = parse_frame_meta(update.meta, len(moving), len(self.scene.point_lights))
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
        for o, xf in zip(moving, m.xf):   # both checked invertible (scene.wire, .wire)
            self._moving[o.object_id].m = xf.astype(np.float64) @ np.linalg.inv(o.transform)  # model = holder.m @ transform
        if self.scene.sun is not None:
            self.scene.sun.intensity = Schedule.constant(m.sun)
        for pl, v in zip(self.scene.point_lights, m.lights):
            pl.intensity = Schedule.constant(float(v))
        if probes is not None:
            self.probes.scatter(*probes)
        self.has_content = True       # the scene is here: draw it, the indirect light filling in as probes arrive

    def render(self, pose: Pose, t_s: float) -> ClientFrame:
        out = self.renderer.render(self.scene, t_s, pose, self.intrinsics)
        return ClientFrame(out.color, None, {"cli_probes": float(self.probes.received.sum())})


__all__ = ["ProbesClient"]
