"""``probes`` server half and the shared GI server (paper sections 3.1-3.4).

**GI server** (:class:`ProbesProducer`, once per server frame for every session): the
scene's DDGI volume (:mod:`splitrender.render.ddgi`, on the server's renderer, so the ground
truth and the server share the capture) relit at the newest time on the ``gi_hz`` grid,
then coded: 10-bit colour codes and float16 distance moments per probe.  A still scene
gives the same codes at every update.

**Per client** (:class:`ProbesServer`):

1. select the probes that are active, differ texel for texel from what this client
   last received, and light points a 360-degree view at its predicted position sees
   (``pvs = "view"``: six ``pvs_res`` depth faces; the eight probes around each
   visible point);
2. write the selected probes into their stable slots of the two update pictures (the
   other slots keep what they held, so the codec's P-frames skip them) and list them in
   the ``index`` data stream; each picture goes only when some selected probe's colour
   (or visibility) changed, so a light change sends no visibility and moving geometry
   no colour it did not change; an update with no probe for this client sends no
   picture and no index (the codec's frames are probe updates, so ``gop`` counts them);
3. **losses** (ours, where the paper resends every selected probe on a keyframe request
   or a loss): each update's probe ids are remembered; when the client reports an
   update lost, its probes count as never sent and go again.  When the loss broke the
   codec's chain (an update at or after the newest I-frame), or on a keyframe request,
   the streams restart with an I-frame on an **empty canvas**:
   the pictures hold only the probes sent from then on, not every slot, so an I-frame
   after a loss costs what was lost, not the whole volume.  ``refresh_probes`` > 0 also
   spreads the probes a client lacks (the first update, a keyframe request, a loss)
   over frames, that many a frame, nearest the client first: smaller frames, each more
   likely to arrive whole under bursty loss;
4. send each frame's transforms of the moving objects (in scene order) and light
   intensities in the metadata; the scene itself goes once, in the session data
   (:mod:`splitrender.scene.wire`);
5. **the client's operating point** (rate adaptation, ``--adapt full``: :meth:`ServerHalf.set_knobs` sets it; the GI
   server is untouched): ``probe_div`` > 1 holds the probes of the GI updates this client skips (the frames carry
   the metadata alone), ``probe_bits`` and ``vis_bits`` round what is selected and sent (:func:`round_codes`,
   :func:`round_moments`), and a probe is new to the client where it differs at the precision it was last sent at
   (or the present one, where coarser), so a coarser point sends less at once and a finer one refines each probe
   as it next changes.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from ...codecs.video import VideoCodecConfig
from ...errors import ConfigError
from ...render.ddgi import IRR_CORE, VIS_CORE, DdgiSettings, gi_time, probe_grid
from ...gi.stream import COLOR_MAX_CODE, color_frame, encode_index_list, encode_irradiance, grid_shape, visibility_frame, visibility_width
from ...render.octa import CUBE_FACES
from ...scene.pose import CameraIntrinsics, Pose, quat_from_matrix3
from ...scene.wire import scene_to_data
from ..base import DataStreamSpec, SceneProducer, ServerContext, ServerHalf, StreamSpec, Update
from .config import ProbesConfig

META_VERSION = 2
SENT_HISTORY = 512
"""Frames whose probe ids a session remembers, to resend them when the client reports the frame lost."""


def round_codes(codes: np.ndarray, bits: int) -> np.ndarray:
    """10-bit irradiance codes rounded to ``bits`` bits (a code stays 10 bits wide, its low ``10 - bits`` bits those of
    the nearest step; 0, no light, stays 0 and a lit code stays lit)."""
    s = 10 - bits
    if s <= 0:
        return codes
    c = codes.astype(np.int32)
    q = (((c - 1 + (1 << (s - 1))) >> s) << s) + 1
    return np.where(c > 0, np.minimum(q, COLOR_MAX_CODE), 0).astype(np.uint16)


def round_moments(moments: np.ndarray, bits: int) -> np.ndarray:
    """float16 distance moments with their 10-bit mantissas rounded to ``bits`` bits (to the nearest; a value the
    rounding would carry past the largest finite float16 is cut instead)."""
    s = 10 - bits
    if s <= 0:
        return moments
    u = moments.view(np.uint16).astype(np.int32)
    mask = 0xFFFF & ~((1 << s) - 1)
    r = (u + (1 << (s - 1))) & mask
    r = np.where((r & 0x7C00) == 0x7C00, u & mask, r)      # carried into inf: cut instead
    return r.astype(np.uint16).view(np.float16)


def _differs(new: np.ndarray, old: np.ndarray, at: np.ndarray, rnd: Any) -> np.ndarray:
    """Per probe, whether ``new`` and ``old`` (one picture's values, a probe per row) differ when both are rounded by
    ``rnd`` (:func:`round_codes`, :func:`round_moments`) to that probe's precision ``at`` (bits); compared bit for bit."""
    out = np.zeros(len(at), bool)
    for b in np.unique(at):
        m = at == b
        a, c = rnd(new[m], int(b)), rnd(old[m], int(b))
        out[m] = (a.view(np.uint16) != c.view(np.uint16)).any(axis=tuple(range(1, a.ndim)))
    return out


def _require_gi(scene: Any) -> None:
    if getattr(scene, "gi", "none") != "ddgi":
        import shlex

        from ...scene.loader import with_gi_spec

        spec = getattr(scene, "spec", None) or scene.name
        raise ConfigError(f"probes: scene {spec!r} has no global illumination to stream; use a scene with GI "
                          f"(the default scene, or this one with it: --scene {shlex.quote(with_gi_spec(spec))})")


class ProbesProducer(SceneProducer):
    """The GI server: one probe update per ``gi_hz`` tick, coded once for every session."""

    def __init__(self, *a: Any, **kw: Any) -> None:
        super().__init__(*a, **kw)
        _require_gi(self.scene)
        if self.renderer is not None:      # capture the probes' G-buffers now, with the scene's set-up, not on the clock
            self.renderer.gi_volume(self.scene)
        self._last: dict[str, Any] | None = None
        self._ms = 0.0
        self.traces = 0

    def prepare(self, frame_id: int, t_s: float) -> dict[str, Any]:
        return self.state(self.renderer, t_s)

    def state(self, renderer: Any, t_s: float) -> dict[str, Any]:
        """The coded probes at the newest update time before ``t_s`` (relit only when that time changes)."""
        cfg = self.config
        assert isinstance(cfg, ProbesConfig)
        t_gi = gi_time(t_s, cfg.gi_hz)
        if self._last is not None and self._last["t_gi"] == t_gi:
            self._ms = 0.0
            return self._last
        w0 = time.perf_counter()
        vol = renderer.gi_volume(self.scene)
        vol.update(t_gi)
        n = vol.count
        self._last = {"t_gi": t_gi, "active": vol.active.copy(),
                      "codes": encode_irradiance(vol.irradiance).reshape(n, IRR_CORE, IRR_CORE, 3),
                      "moments": vol.moments.astype(np.float16).reshape(n, VIS_CORE, VIS_CORE, 2)}
        self.traces += 1
        self._ms = (time.perf_counter() - w0) * 1e3
        return self._last

    def stats(self) -> dict[str, float]:
        return {"gi_ms": self._ms, "gi_traces": float(self.traces)}


class ProbesServer(ServerHalf):
    """Light probe streaming, server half (per session)."""

    config: ProbesConfig

    def __init__(self, *a: Any, **kw: Any) -> None:
        super().__init__(*a, **kw)
        _require_gi(self.scene)
        if not isinstance(self.producer, ProbesProducer):
            self.producer = ProbesProducer(self.config, self.scene, self.server_fps, None)
        counts = tuple(int(c) for c in self.scene.gi_probes)
        self.count = int(np.prod(counts))
        lo, hi = self.scene.bounds()
        self.origin, self.spacing = probe_grid(lo, hi, counts)  # type: ignore[arg-type]
        self.counts = counts
        cols, rows = grid_shape(self.count)
        self._color_size = (cols * IRR_CORE, rows * IRR_CORE)
        self._vis_size = (visibility_width(self.count), rows * VIS_CORE)
        self.sent_codes = np.zeros((self.count, IRR_CORE, IRR_CORE, 3), np.uint16)
        self.sent_moments = np.zeros((self.count, VIS_CORE, VIS_CORE, 2), np.float16)
        self.sent = np.zeros(self.count, bool)
        self.sent_bits = np.full(self.count, 10, np.int8)            # the precision each probe was last sent at
        self.sent_vbits = np.full(self.count, 10, np.int8)
        self.canvas_codes = np.zeros_like(self.sent_codes)       # what the pictures hold (emptied at each I-frame)
        self.canvas_moments = np.zeros_like(self.sent_moments)
        self.canvas_set_c = np.zeros(self.count, bool)            # slots written since the last I-frame
        self.canvas_set_v = np.zeros(self.count, bool)
        self._sent_in: dict[int, np.ndarray] = {}                 # frame id -> the probes it carried
        self._idr_frame = 0
        k, j, i = np.meshgrid(*(np.arange(c) for c in counts[::-1]), indexing="ij")
        self.positions = self.origin + np.stack([i, j, k], -1).reshape(-1, 3) * self.spacing
        self._stats: dict[str, float] = {}
        self._frames = 0
        self._gi_sent: int | None = None                           # the GI update this client last got probes of

    def streams(self) -> list[Any]:
        fps, gop = self.server_fps, self.config.gop
        color = VideoCodecConfig(codec="hevc", pix_fmt="gbrp10le", input_format="gbrp10le", lossless=True, crf=None, gop=gop,
                                 preset=self.config.preset, fps=fps)
        if self.config.vis_lossy:          # the ablation: float16 bytes through a lossy codec
            vis = VideoCodecConfig(codec="hevc", pix_fmt="yuv444p", input_format="rgb24", crf=self.config.crf or 23.0,
                                   gop=gop, preset=self.config.preset, fps=fps)
        else:
            vis = VideoCodecConfig(codec="hevc", pix_fmt="gbrp", input_format="rgb24", lossless=True, crf=None, gop=gop,
                                   preset=self.config.preset, fps=fps)
        return [StreamSpec("color", color, *self._color_size), StreamSpec("vis", vis, *self._vis_size),
                DataStreamSpec("index", "reliable")]

    def session_data(self) -> dict[str, Any]:
        return {"v": META_VERSION, "scene": scene_to_data(self.scene), "origin": [float(x) for x in self.origin],
                "spacing": [float(x) for x in self.spacing], "counts": list(self.counts),
                "bias": float(DdgiSettings().bias), "vis_lossy": bool(self.config.vis_lossy)}

    # ------------------------------------------------------------------ visibility
    def visible_probes(self, ctx: ServerContext) -> np.ndarray:
        """(count,) bool: probes around the points a 360-degree view at the predicted position sees."""
        res = self.config.pvs_res
        intr = CameraIntrinsics(res, res, 90.0)
        eye = np.asarray(ctx.target_pose.position, np.float64)
        c = (np.arange(res) + 0.5) / res * 2.0 - 1.0
        u, v = np.meshgrid(c, -c)                        # rows from the top, as the renderer returns them
        pts = []
        for f, up in CUBE_FACES:
            fw, upv = np.asarray(f, np.float64), np.asarray(up, np.float64)
            r = np.cross(fw, upv)
            pose = Pose(eye, quat_from_matrix3(np.stack([r, upv, -fw], axis=1)))
            depth = ctx.renderer.render(self.scene, ctx.t_s, pose, intr, outputs=("depth",)).depth
            ok = np.isfinite(depth) & (depth > 0)
            d = depth[ok][:, None]
            pts.append(eye + d * (fw[None] + u[ok][:, None] * r[None] + v[ok][:, None] * upv[None]))
        p = np.concatenate(pts) if pts else np.zeros((0, 3))
        cx, cy, cz = self.counts
        rel = (p - self.origin) / self.spacing
        base = np.clip(np.floor(rel).astype(np.int64), 0, np.array([cx, cy, cz]) - 2)
        out = np.zeros(self.count, bool)
        for k in range(8):
            q = np.minimum(base + np.array([k & 1, (k >> 1) & 1, (k >> 2) & 1]), np.array([cx, cy, cz]) - 1)
            out[q[:, 0] + cx * (q[:, 1] + cy * q[:, 2])] = True
        return out

    # ------------------------------------------------------------------ produce
    def produce(self, ctx: ServerContext) -> Update:
        t0 = time.perf_counter()
        prod = self.producer
        assert isinstance(prod, ProbesProducer)
        shared = ctx.shared if isinstance(ctx.shared, dict) and "codes" in ctx.shared else prod.state(ctx.renderer, ctx.t_s)
        cfg = self.config
        # this client's precision: a probe is new to it where it differs at that precision
        bits, vbits = cfg.probe_bits, cfg.vis_bits
        codes, moments, active = round_codes(shared["codes"], bits), round_moments(shared["moments"], vbits), shared["active"]
        gi_update = int(round(float(shared["t_gi"]) * cfg.gi_hz))
        # not this client's update: one GI update in probe_div is (more of the one it last got may still go)
        held = self._gi_sent is not None and 0 < gi_update - self._gi_sent < cfg.probe_div
        fb = ctx.feedback
        lost = sorted({f for s in ("color", "vis", "index") for f in fb.newly_lost(s)})
        for f in lost:                      # the probes of a lost update: the client never took them
            ids = self._sent_in.pop(f, None)
            if ids is not None:
                self.sent[ids] = False
        # a new I-frame when the client's decoders lost the chain (a loss at or after the newest I-frame), on a
        # keyframe request, and first; it starts from an empty canvas, so it holds only what goes now.  A keyframe
        # request restarts the codec only: the client keeps its probe copy, and what it missed it reports lost
        restart = self._frames == 0 or ctx.keyframe_requested or any(f >= self._idr_frame for f in lost)
        if restart:
            self.canvas_codes[:] = 0
            self.canvas_moments[:] = 0
            self.canvas_set_c[:] = False
            self.canvas_set_v[:] = False
            self._idr_frame = ctx.frame_id
        visible = self.visible_probes(ctx) if self.config.pvs == "view" else np.ones(self.count, bool)
        # a probe is new to this client where it differs at the precision it was sent at, or at this client's
        # present one where that is coarser: a finer precision refines each probe when it next changes, not all at once
        changed_c = ~self.sent | _differs(shared["codes"], self.sent_codes, np.minimum(self.sent_bits, bits), round_codes)
        changed_v = ~self.sent | _differs(shared["moments"], self.sent_moments, np.minimum(self.sent_vbits, vbits),
                                          round_moments)
        changed = changed_c | changed_v
        want = active & visible & changed & (not held)
        cap = self.config.refresh_probes
        backlog = 0
        if cap > 0:                         # probes the client lacks go at most `cap` a frame, the nearest first
            fresh = np.flatnonzero(want & ~self.sent)
            if fresh.size > cap:
                eye = np.asarray(ctx.target_pose.position, np.float64)
                near = fresh[np.argsort(np.linalg.norm(self.positions[fresh] - eye, axis=1), kind="stable")]
                want[near[cap:]] = False
                backlog = int(near.size - cap)
        sel = np.flatnonzero(want)
        # each picture's slot is rewritten only where its own part changed (or holds nothing since the I-frame): a
        # probe that goes for its irradiance keeps its distance moments as sent, and the other way round.  Rewriting
        # both made a coarser precision cost a burst: the first GI update after vis_bits 10 -> 2 rewrote every
        # selected probe's moments at 2 bits, a 157 kB lossless picture against 4 kB (probes, the step trace, 160x90)
        wc = sel[changed_c[sel] | ~self.canvas_set_c[sel]]
        wv = sel[changed_v[sel] | ~self.canvas_set_v[sel]]
        self.sent_codes[wc] = codes[wc]
        self.canvas_codes[wc] = codes[wc]
        self.sent_bits[wc] = bits
        self.canvas_set_c[wc] = True
        self.sent_moments[wv] = moments[wv]
        self.canvas_moments[wv] = moments[wv]
        self.sent_vbits[wv] = vbits
        self.canvas_set_v[wv] = True
        self.sent[sel] = True
        if sel.size:
            self._gi_sent = gi_update
        sc = self.scene
        models = np.array([o.model_matrix(ctx.t_s) for o in sc.objects if o.dynamic], np.float32).reshape(-1, 4, 4)
        meta = {"v": META_VERSION, "t_gi": float(shared["t_gi"]), "xf": models,
                "sun": float(sc.sun.intensity.value(ctx.t_s)) if sc.sun is not None else 0.0,
                "lights": [float(pl.intensity.value(ctx.t_s)) for pl in sc.point_lights]}
        self._frames += 1
        self._stats = {"probes_sent": float(sel.size), "probes_active": float(active.sum()),
                       "probes_visible": float((active & visible).sum()), "probes_changed": float((active & changed).sum()),
                       "probes_backlog": float(backlog), "probes_held": float(held), "full": float(restart),
                       "lost_updates": float(len(lost)),
                       "probe_ms": (time.perf_counter() - t0) * 1e3}
        if not sel.size and not restart:   # nothing new for this client: the probe streams skip the frame
            return Update(ctx.frame_id, ctx.t_s, ctx.target_pose, {}, meta)
        planes = {}                         # colour and visibility each go only when some selected probe's changed
        if restart or wc.size:
            planes["color"] = color_frame(self.canvas_codes)
        if restart or wv.size:
            planes["vis"] = visibility_frame(self.canvas_moments)
        self._stats.update({"color_sent": float("color" in planes), "vis_sent": float("vis" in planes)})
        self._sent_in[ctx.frame_id] = sel
        while len(self._sent_in) > SENT_HISTORY:
            self._sent_in.pop(next(iter(self._sent_in)))
        return Update(ctx.frame_id, ctx.t_s, ctx.target_pose, planes, meta, force_idr=restart,
                      data={"index": encode_index_list(sel)})

    def stats(self) -> dict[str, float]:
        return dict(self._stats)
