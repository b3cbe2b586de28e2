"""The virtual-time runner: a deterministic discrete-event run of one server and its clients.

Every byte goes through the same transmission path as a live session
(:mod:`splitrender.pipeline`): the handshake, session data, ``FrameMeta`` and
``DataChunk`` messages are framed by real :class:`~splitrender.protocol.Connection`
pairs, video and datagram data are real RTP packets, the client reassembles them in
real jitter buffers and decodes them with the real decoders.  Only the sockets are
replaced: each packet crosses the network model (:mod:`splitrender.netsim`) on a
simulated clock, through its driver (:mod:`splitrender.netsim.driver`: the clock and its events, each direction of
the path as a wire taking datagrams and a TCP stream, each core's one timer).

Timeline (all on the simulated clock, seconds; wall-clock-like µs values on the wire
count from :data:`SIM_EPOCH_US` so messages have the same sizes as live ones):

- Each client's tracker samples its trace at ``tracker_hz``; each pose travels the
  uplink as a small datagram (a lost pose is simply superseded by the next one).
- The server ticks at ``server_fps``.  At tick ``t`` the method's scene producer (if
  any) runs once for all clients; then, per client, the server feeds the poses that
  have arrived to its predictor and predicts the pose at ``t`` plus the latency it has
  *measured* from the client's feedback (as the live server does), asks the server
  half for an update with the client's merged feedback, encodes and packetizes it.
- After ``server_latency_ms`` (``cost_model = "measured"``: the measured shared, server
  and encode milliseconds times ``cost_scale``; a tick that finds the server busy is
  skipped) the frame leaves: control frames as TCP segments over
  the downlink (a lost segment costs one RTO, in order, head-of-line blocking
  included), RTP packets as datagrams (lost, delayed, reordered, duplicated).
- The client's pipeline releases each frame in order once every stream it sent is
  present or known lost (partial delivery); ``decode_latency_ms`` (or its measured
  decode time) later it is applied.
- Everything the protocol decides is the sans-IO session cores' (:mod:`splitrender.pipeline.session`),
  the same ones the live server and client drive: the client core NACKs holes, sends
  PLIs while a video stream waits for a keyframe (at most every
  ``pli_interval_ms``), receiver reports and stall PLIs; the server core
  answers NACKs from its retransmission history (down the media path) and PLIs with an
  IDR, and sends sender reports.  RTCP crosses its own copy of each direction's
  network model (the same impairment, its own random draws).  The runner schedules
  each core's timer at the deadline the core names.
- Each client displays at ``client_fps`` from t = 0: it renders through its client
  half, in its own GL context, at the true pose of that tick (a tick with nothing yet
  shows and scores the black background); the ground truth is rendered at the same
  pose and time with no latency.  The first display of each update sends a Feedback
  (applied and lost frames per stream, display time) up the control uplink.

Wall-clock costs (shared and per-client server work, encode, decode, client render,
ground truth) are measured and recorded, but never move the simulated clock, so a
run is the same on any machine for a given seed.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from .. import metrics
from ..errors import ConfigError, RemoteProtocolError
from ..methods.base import get_method
from ..netsim import Link, parse_path
from ..netsim.driver import TIMER, Clock, Timer, Wire, arrivals
from ..pipeline.frames import decode_work
from ..pipeline.rows import SentBytes, frame_row, run_summary
from ..pipeline import (CLIENT_CODECS, META_STREAM, SESSION_STREAM, ClientHandshake, ClientSession,
                        FrameMaker, Opening, ProducerPool, ReceivedFrame, ServerSession, accept_hello, check_hello,
                        display_frame, method_config, tcp_segments)
from ..pipeline.recording import write_run
from ..pipeline.session import read_hello
from ..pipeline.wire import control_wire_bytes, datagram_wire_bytes
from ..protocol import Welcome
from ..render.gl import create_context, make_current
from ..render.renderer import Renderer
from ..scene.loader import get_scene
from ..scene.model import shift_time
from ..scene.pose import CameraIntrinsics, Pose
from ..scene.predict import PerfectPredictor, prediction_error
from ..scene.trace import get_trace
from .config import RunConfig
from .truth import truth_source

log = logging.getLogger(__name__)

POSE_MESSAGE_BYTES = 64 + 40
SIM_EPOCH_US = 1_735_689_600_000_000
"""Simulated wall clock at t = 0 (2025-01-01T00:00:00Z), so timestamps on the wire have live sizes."""
_SERVER, _DISPLAY = 2, 3
"""Event priorities of the runner's ticks (after the driver's deliveries and timers at one time)."""
ProgressFn = Callable[[int, int], None]


def sim_us(t_s: float) -> int:
    """The simulated wall clock at ``t_s``, µs."""
    return SIM_EPOCH_US + int(round(t_s * 1e6))


@dataclass
class RunResult:
    config: RunConfig
    frames: list[dict[str, Any]] = field(default_factory=list)
    updates: list[dict[str, Any]] = field(default_factory=list)
    summary: dict[str, Any] = field(default_factory=dict)
    images: list[tuple[int, np.ndarray, np.ndarray]] = field(default_factory=list)
    resolved: dict[str, Any] = field(default_factory=dict)
    client_summaries: list[dict[str, Any]] = field(default_factory=list)
    """One summary per client (``summary`` is client 0's, with the run-wide columns)."""

    def write(self, out_dir: str | Path) -> Path:
        """Write frames.csv, updates.csv, summary.csv (a row per client), config.toml and kept images into ``out_dir``
        (:func:`~splitrender.pipeline.recording.write_run`)."""
        return write_run(Path(out_dir), self.frames, self.updates, self.client_summaries or [self.summary],
                         self.config.toml(self.resolved), self.images)


class _ShiftedTrace:
    """A trace seen ``offset_s`` later (client ``i`` of a many-client run)."""

    def __init__(self, trace: Any, offset_s: float) -> None:
        self.trace, self.offset_s = trace, offset_s
        self.duration_s = max(0.0, trace.duration_s - offset_s)

    def pose_at(self, t: float) -> Pose:
        return self.trace.pose_at(min(t + self.offset_s, self.trace.duration_s))  # type: ignore[no-any-return]


@dataclass
class _Client:
    """One session of a run: its server side, links and client side (built once its handshake is done)."""

    index: int
    trace: Any
    up: Link
    """The poses' uplink (their deliveries are worked out before the run: the model is deterministic)."""
    ctrl: Wire
    down: Wire
    """The control connection up; the control connection and the media down."""
    rtcp_up: Wire
    rtcp_down: Wire
    """RTCP's own copies of the path's two directions (same impairment, own random draws)."""
    # server side
    maker: FrameMaker
    """The session's server half and encoders (its frames are made here, on the runner's GL thread)."""
    core_s: ServerSession
    """The server's session core (poses, feedback, keyframes, frame orders, NACK answers, sender reports)."""
    # client side
    welcome: Welcome
    """The Welcome the client decoded (its SDPs carry the encoders' parameter sets, as live; the fuzz seeds and the SDP
    tests read it)."""
    chalf: Any
    gl: Any
    core: ClientSession
    """The client's session core (RTCP, NACK, PLI, playout delay, stalls, feedback)."""
    bytes: SentBytes
    """The wire bytes the server sent per stream, in all and over the last second."""
    server_timer: Timer = field(init=False)
    timer: Timer = field(init=False)
    arrivals: list[tuple[float, float]] = field(default_factory=list)
    arrival_idx: int = 0
    sent: dict[int, tuple[dict[str, Any], float]] = field(default_factory=dict)
    """Each frame sent: its update row and the sample time of the newest pose its order had (s)."""
    protocol_errors: int = 0
    packets_lost: int = 0
    """RTP datagrams the downlink dropped (media, FEC and retransmissions)."""
    frames: list[dict[str, Any]] = field(default_factory=list)
    updates: list[dict[str, Any]] = field(default_factory=list)


class VirtualTimeRun:
    """One run; call :meth:`run`.  Holds the GL renderer (one thread owns it)."""

    def __init__(self, cfg: RunConfig, renderer: Renderer | None = None, progress: ProgressFn | None = None) -> None:
        self.cfg = cfg
        self.progress = progress
        self.spec = get_method(cfg.method)
        self.mcfg = method_config(cfg.method, cfg.method_params)
        self.scene = shift_time(get_scene(cfg.scene), cfg.scene_time_offset_s)
        self.trace = get_trace(cfg.trace, scene=self.scene, fov_y_deg=cfg.fov_y_deg, aspect=cfg.width / cfg.height)
        names = cfg.client_traces or (cfg.trace,)
        self.traces = [_ShiftedTrace(self.trace if names[i % len(names)] == cfg.trace else
                                     get_trace(names[i % len(names)], scene=self.scene, fov_y_deg=cfg.fov_y_deg,
                                               aspect=cfg.width / cfg.height),
                                     i * cfg.client_offset_s) for i in range(cfg.clients)]
        self.path = parse_path(cfg.network)
        self.intr = CameraIntrinsics(cfg.width, cfg.height, cfg.fov_y_deg)
        self.renderer = renderer or Renderer()
        make_current(self.renderer.ctx)
        # relit probe states are shared across runs on one renderer, but not where wall-clock costs go on the clock
        self.renderer.probe_states().enabled = cfg.cost_model != "measured"
        self.truth = truth_source(cfg.truth_cache, self.renderer, self.scene, self.trace, self.intr, cfg.client_fps,
                                  cfg.supersample)
        full = min(t.duration_s for t in self.traces)
        if full <= 0:
            raise ConfigError(f"run config client_offset_s: {cfg.client_offset_s} s leaves no trace for client {cfg.clients - 1}")
        self.duration_s = min(cfg.duration_s or full, full)
        self.clock = Clock()
        self.server_free_s = 0.0
        """When the server finishes its current frame (``cost_model = "measured"``)."""
        self.server_skipped = 0

    @property
    def now(self) -> float:
        """The simulated clock, s."""
        return self.clock.now

    # ------------------------------------------------------------------ set-up

    def _setup(self, i: int, seeds: list[np.random.SeedSequence], pool: ProducerPool) -> _Client:
        cfg = self.cfg
        n = cfg.clients
        up, down = self.path.uplink, self.path.downlink
        # handshake through a real Connection pair (set-up time is not simulated), the client's the same sans-IO
        # core as the live client's; it decodes what the live client does (its method's codec first)
        opts = cfg.client_options()
        hs = ClientHandshake((cfg.method,), dataclasses.replace(opts.limits, max_session_bytes=cfg.max_session_bytes),
                             (cfg.width, cfg.height))
        hello = hs.make_hello(dict.fromkeys((self.mcfg.codec, *CLIENT_CODECS)), cfg.client_fps)
        check_hello(hello, cfg.width * cfg.height)
        # the server's side: its end of the control connection reads the Hello; the half here, then the one handshake
        # every front door runs
        sconn = read_hello(hs.hello(hello))
        make_current(self.renderer.ctx)
        opening = Opening(cfg.method, self.mcfg, self.intr)
        maker = FrameMaker(opening, pool)
        acc = accept_hello(hello, f"sim{i}", opening, maker.specs, maker.session_blob, sconn, cfg, cfg.server_options(),
                           parameter_sets=maker.encoder.described_sets(),
                           subject=getattr(self.scene, "subject", None), rng=np.random.default_rng(seeds[3 * n + i]),
                           core_rng=np.random.default_rng(seeds[6 * n + 2 * i + 1]), clock_offset_us=SIM_EPOCH_US,
                           predictor=PerfectPredictor(self.traces[i]) if cfg.predictor == "perfect" else None)
        acc.core.record_rows = False   # a run keeps its own tables
        frames = acc.core.data_to_send(0.0)   # the Welcome and the session data
        sent = SentBytes([SESSION_STREAM, META_STREAM, *(s.name for s in maker.specs)])
        sent.add(SESSION_STREAM, sum(control_wire_bytes(len(f)) for f in frames))
        assert hs.receive_data(b"".join(frames)) and hs.welcome is not None and hs.terms is not None
        core = hs.session(opts, SIM_EPOCH_US, np.random.default_rng(seeds[6 * n + 2 * i]))
        core.release_delay_ms = self._decode_delay_ms   # type: ignore[assignment]
        gl = create_context()  # the client half's own context: it cannot touch the server's GL objects
        c = _Client(i, self.traces[i], Link(up, np.random.default_rng(seeds[3 * i])),
                    *(Wire(self.clock, Link(spec, np.random.default_rng(seeds[k]))) for spec, k in
                      ((up, 3 * i + 1), (down, 3 * i + 2), (up, 4 * n + 2 * i), (down, 4 * n + 2 * i + 1))),
                    maker, acc.core, hs.welcome, hs.client_half(gl), gl, core, sent)
        make_current(self.renderer.ctx)
        c.server_timer = Timer(self.clock, lambda: self._server_out(c), self.duration_s + 1.0, by_deadline=True)
        c.timer = Timer(self.clock, lambda: self._client_timer_now(c), self.duration_s + 1.0 / cfg.client_fps,
                        by_deadline=False)
        self._pose_up(c, 0.0)   # the Hello carries the first pose
        c.arrivals = arrivals(c.up, (k / cfg.tracker_hz for k in range(int(self.duration_s * cfg.tracker_hz) + 1)),
                              POSE_MESSAGE_BYTES)   # the tracker's poses up: worked out before the run
        return c

    # ------------------------------------------------------------------ run

    def run(self) -> RunResult:
        before, self.renderer.supersample = self.renderer.supersample, self.cfg.supersample
        try:
            return self._run()
        finally:
            self.renderer.supersample = before  # the renderer may be shared with the caller

    def _run(self) -> RunResult:
        cfg = self.cfg
        seeds = np.random.SeedSequence(cfg.seed).spawn(8 * cfg.clients)   # the first 4n as before the session cores
        pool = ProducerPool(self.scene, cfg.server_fps, self.renderer)
        clients = [self._setup(i, seeds, pool) for i in range(cfg.clients)]
        self.clients = clients
        self.pool = pool
        result = RunResult(cfg, resolved={"method": dataclasses.asdict(self.mcfg), "network": dataclasses.asdict(self.path)})
        n_server = int(math.floor(self.duration_s * cfg.server_fps)) + 1
        n_display = int(math.floor(self.duration_s * cfg.client_fps)) + 1
        for f in range(n_server):
            self.clock.at(f / cfg.server_fps, _SERVER, self._server_tick, f, pool, result)
        for di in range(n_display):
            self.clock.at(di / cfg.client_fps, _DISPLAY, self._display_tick, di, n_display, result)
        for c in clients:   # both cores start with the session at t = 0
            c.core.start(0.0)
            c.core_s.start(0.0)
            self._client_out(c)
            self._server_out(c)
        self.clock.run()
        make_current(self.renderer.ctx)
        for c in clients:
            c.gl.release()
        make_current(self.renderer.ctx)
        result.frames = [r for c in clients for r in c.frames]
        result.updates = [r for c in clients for r in c.updates]
        result.client_summaries = [self._summary(c) for c in clients]
        result.summary = dict(result.client_summaries[0])
        if cfg.clients > 1:
            result.summary["clients"] = cfg.clients
        return result

    # ------------------------------------------------------------------ server

    def _pose_up(self, c: _Client, ts: float) -> None:
        """The tracker's sample measured at ``ts`` reaches the server (stamped as the live client stamps it)."""
        c.core_s.receive_pose(ts, c.trace.pose_at(ts), sim_us(ts), int(round(ts * self.cfg.tracker_hz)))

    def _server_tick(self, f: int, pool: ProducerPool, result: RunResult) -> None:
        cfg, t_f = self.cfg, f / self.cfg.server_fps
        measured = cfg.cost_model == "measured"
        if measured and self.server_free_s > t_f + 1e-9:  # still busy with the last frame: this tick is skipped
            self.server_skipped += 1
            return
        make_current(self.renderer.ctx)
        busy_ms = 0.0  # measured server time so far this tick (sessions are served one after another)
        for c in self.clients:
            while c.arrival_idx < len(c.arrivals) and c.arrivals[c.arrival_idx][0] <= t_f:
                self._pose_up(c, c.arrivals[c.arrival_idx][1])   # every front door's rule: newer than the newest taken
                c.arrival_idx += 1
            order = c.core_s.order_frame(f, f, t_f, t_f * 1000, client=c.index)
            if order is None:      # the operating point sends one tick in frame_div
                continue
            enc, stats, stages = c.maker.make(order)
            busy_ms += stages["frame_ms"]
            cost_ms = busy_ms * cfg.cost_scale if measured else cfg.server_latency_ms
            send_t = t_f + cost_ms / 1000.0
            self.server_free_s = max(self.server_free_s, send_t)
            timing = {"render": int(round(cost_ms * 1000)), "encode": 0, "encoded_at": sim_us(send_t)}
            # the half's wall-clock stage times ride in the envelope only where they are on the clock too: their
            # bytes would otherwise make two runs of one seed differ (and, adapting, decide differently)
            wire_stats = stats if measured else {k: v for k, v in stats.items() if not k.endswith("_ms")}
            # the frame leaves when its modelled encoding ends (its control frames, then its datagrams), through the
            # core's one way out
            out = c.core_s.frame_encoded(order, enc, t_f * 1000, sim_us(t_f), timing, wire_stats,
                                         send_ms=send_t * 1000)
            self.clock.at(send_t, TIMER, self._server_control, c)   # its control frames are due then
            self._server_out(c)
            c.bytes.frame(t_f, out.wire_bytes)
            pred_cm, pred_deg = prediction_error(order.target_pose, c.trace.pose_at(order.target_t_s))
            # the tick's shared work is the pool's (a run's sessions share one producer), not this session's share
            shared = pool.shared_ms.get(self.spec.name, 0.0) if self.spec.producer is not None else 0.0
            row = {"client": c.index,
                   **c.core_s.update_row(order, out, enc, {**stages, "shared_ms": shared}, c.bytes.total),
                   "delivered": "", "missing": "", "cost_ms": cost_ms, "pred_err_cm": pred_cm, "pred_err_deg": pred_deg,
                   "arrival_s": math.nan}
            row.update({f"srv_{k}": v for k, v in stats.items()})
            row.update({f"shared_{k}": v for k, v in pool.stats(self.spec.name).items()})
            c.sent[f] = (row, order.latest_pose_t_s)
            c.updates.append(row)

    def _server_out(self, c: _Client) -> None:
        """What the server core sends now (its one way out; a frame's control frames at its send time:
        :meth:`_server_control`): media, FEC, retransmissions and probes down the media path, sender reports over
        RTCP's copy of the downlink; then its one timer is armed."""
        for d in c.core_s.datagrams_to_send(self.now * 1000):
            if d.kind == "rtcp":
                c.rtcp_down.datagram(len(d.data) + 28, self._deliver_datagram, c, d.data)
            else:
                c.packets_lost += not c.down.datagram(len(d.data) + 28, self._deliver_datagram, c, d.data)
            if d.kind == "probe":
                c.bytes.add("probe", datagram_wire_bytes(len(d.data)))
        c.server_timer.arm(c.core_s.get_timer() / 1000)

    def _server_control(self, c: _Client) -> None:
        """The server core's control frames due now, down the TCP stream, each a write."""
        if frames := c.core_s.data_to_send(self.now * 1000):
            c.down.stream([(data, tcp_segments(len(data))) for data in frames], self._deliver_control, c)

    def _server_receive(self, c: _Client, data: bytes) -> None:
        c.core_s.receive_data(data)
        while c.core_s.next_event(self.now * 1000) is not None:   # the core takes what the server reads
            pass

    def _server_rtcp(self, c: _Client, data: bytes) -> None:
        """A client RTCP datagram reaches the server; NACKed packets go back down the media path."""
        c.core_s.receive_datagram(data, self.now * 1000)
        self._server_out(c)

    # ------------------------------------------------------------------ client

    def _deliver_control(self, c: _Client, data: bytes) -> None:
        now_ms = self.now * 1000
        try:
            c.core.receive_data(data, now_ms)
        except RemoteProtocolError as exc:  # a malformed update: counted, the run goes on
            c.protocol_errors += 1
            log.warning("run %s client %d: %s", self.cfg.method, c.index, exc)
        self._client_out(c)

    def _deliver_datagram(self, c: _Client, data: bytes) -> None:
        c.core.receive_datagram(data, self.now * 1000)
        self._decode(c)
        self._client_out(c)

    def _decode(self, c: _Client) -> None:
        """Decode what the client core released (its keyframe-skip rule first), timing it for the display queue."""
        for w in c.core.work_to_decode():
            if not c.core.skips_decode(w, self.now * 1000):
                res, decode_ms = decode_work(w)
                c.core.on_decoded(w, res, self.now * 1000, decode_ms)

    def _decode_delay_ms(self, rf: ReceivedFrame) -> float:
        """A frame the client core releases is displayable its modelled (or measured: its ``decode_ms``) decode time
        later."""
        return rf.decode_ms * self.cfg.cost_scale if self.cfg.cost_model == "measured" else self.cfg.decode_latency_ms

    def _released(self, c: _Client, rf: ReceivedFrame) -> None:
        """A released frame's delivery in its update row (its first release's)."""
        row = c.sent.get(rf.update.frame_id, ({}, 0.0))[0]
        if row.get("delivered") == "":
            row["delivered"] = int(rf.update.complete)
            row["missing"] = ";".join(sorted(rf.update.missing))
            row["arrival_s"] = rf.received_ms / 1000.0

    def _client_timer_now(self, c: _Client) -> None:
        c.core.handle_timer(self.now * 1000)
        self._decode(c)
        self._client_out(c)

    def _client_out(self, c: _Client) -> None:
        """What the client core wants sent (control bytes over the uplink as TCP segments, RTCP over its copy of
        the uplink), its events, its next timer."""
        if control := c.core.data_to_send():
            c.ctrl.stream([(control, tcp_segments(len(control)))], self._server_receive, c)
        for data in c.core.datagrams_to_send():
            c.rtcp_up.datagram(len(data) + 28, self._server_rtcp, c, data)
        for rf in c.core.take_events(f"run {self.cfg.method} client {c.index}", virtual=True):
            self._released(c, rf)
        c.timer.arm(c.core.get_timer() / 1000)

    def _display_tick(self, di: int, n_display: int, result: RunResult) -> None:
        t_d = di / self.cfg.client_fps
        for c in self.clients:
            self._display_one(c, di, t_d, result)
        if self.progress:
            self.progress(di + 1, n_display)

    def _display_one(self, c: _Client, di: int, t_d: float, result: RunResult) -> None:
        cfg = self.cfg
        self._client_timer_now(c)   # timeouts due at this tick first, as the live client's timer task would
        now_ms = t_d * 1000
        make_current(c.gl)
        new = c.core.display_tick(None, now_ms, hold=False)[1] or []   # every driver's rule (virtual time holds none)
        decode_ms = new[-1].decode_ms if new else math.nan
        true_pose = c.trace.pose_at(t_d)
        drawn = display_frame(c.chalf, new, true_pose, t_d, (cfg.width, cfg.height), f"run {cfg.method}")
        # the core's rule: a blank tick (nothing shown yet, or only updates whose content was lost) names no update;
        # the first display of a shown update sends its Feedback with the tick's other output
        shown = c.core.showing(new, drawn.ok, c.chalf.has_content, now_ms)
        make_current(self.renderer.ctx)
        fid = shown.update.frame_id if shown is not None else None
        sent, pose_t = c.sent.get(fid, ({}, math.nan))   # type: ignore[arg-type]
        row: dict[str, Any] = {"client": c.index, **frame_row(
            di, t_d, fid, t_d, shown.update.t_s if shown is not None else math.nan, pose_t, drawn.client_ms, decode_ms)}
        row["pred_err_cm"], row["pred_err_deg"] = sent.get("pred_err_cm", math.nan), sent.get("pred_err_deg", math.nan)
        row.update(c.bytes.kbps(t_d))   # what the server sent over the last second
        if cfg.metrics:
            w0 = time.perf_counter()
            gt_out = self.truth.render(self.scene, t_d, true_pose, self.intr, ("color", "object_id"))
            gt = gt_out.color
            row["gt_ms"] = getattr(gt_out, "render_ms", None) or (time.perf_counter() - w0) * 1000  # a cache hit: its render time
            row.update(metrics.score_frame(drawn.frame.color, drawn.frame.holes, gt, gt_out.object_id > 0,
                                           bool(cfg.flip_every) and di % cfg.flip_every == 0, cfg.ssim_sigma,
                                           truth_model=self.scene.model_mask(gt_out.object_id)))
            if cfg.save_images_every and di % cfg.save_images_every == 0 and c.index == 0:
                result.images.append((di, drawn.frame.color, gt))
        row.update(drawn.columns)
        c.frames.append(row)
        self._client_out(c)

    def _summary(self, c: _Client) -> dict[str, Any]:
        """Client ``c``'s summary row (:func:`~splitrender.pipeline.rows.run_summary`), over the run and one server
        frame interval."""
        dur = self.duration_s + 1.0 / self.cfg.server_fps
        return run_summary(self.cfg, c.index, c.frames, c.updates, c.bytes.total, dur, self.server_skipped,
                           c.protocol_errors, c.packets_lost, c.core.all_counters(), c.core_s.counters,
                           c.core_s.summary(c.updates))


def run(cfg: RunConfig, out_dir: str | Path | None = None, renderer: Renderer | None = None, progress: ProgressFn | None = None) -> RunResult:
    """Run ``cfg`` in virtual time; write CSVs and the resolved config when ``out_dir`` is given."""
    res = VirtualTimeRun(cfg, renderer, progress).run()
    if out_dir is not None:
        res.write(out_dir)
    return res
