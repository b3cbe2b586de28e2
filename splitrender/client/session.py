"""The live headless client: poses up, RTP/FrameMeta down, decode, display, record.

Task layout (one ``asyncio.TaskGroup`` owned by :meth:`LiveClient.run`):

* ``poses``: samples the camera trace at ``tracker_hz`` and sends ``Pose`` messages;
* ``control``: reads FrameMeta (kept until its planes are decoded), Stats, Bye, Error;
* ``rtcp``: binds the UDP path (receiver reports until the first RTP packet), sends
  generic NACKs for holes older than ``nack_delay_ms``, PLIs while a jitter buffer
  needs a keyframe, periodic receiver reports, and applies jitter-buffer timeouts;
* ``decode``: decodes every completed access unit in order on a decoder thread and
  matches planes to their FrameMeta by ``(stream, RTP timestamp)``;
* ``display``: the display clock at ``display_hz``; each tick applies the updates that
  became ready, renders through the method's client half on the client's GL thread
  at the trace pose of that instant, records the row (and image) and sends Feedback
  the first time an update is shown.  It ends the run after ``duration_s``.

Times on the wire are wall-clock µs (:func:`~splitrender.transport.control.wall_us`);
durations are measured with ``time.perf_counter``.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import json
import logging
import math
import time
from collections import OrderedDict, deque
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from splitrender.codecs.meta import parse_update_envelope, unpack_meta
from splitrender.codecs.video import VideoDecoder
from splitrender.errors import CodecError, RemoteProtocolError, SplitRenderError
from splitrender.methods.base import DecodedUpdate, get_method, make_config
from splitrender.protocol import (
    PROTOCOL_VERSION,
    AccessUnit,
    Bye,
    ClientConnection,
    Error,
    Feedback,
    FrameMeta,
    GenericNack,
    Hello,
    JitterBuffer,
    PictureLossIndication,
    Pose,
    ReceiverReport,
    ReceiverStatistics,
    ReportBlock,
    RtpError,
    RtpPacket,
    SenderReport,
    Stats,
    Welcome,
    is_rtcp,
    parse_rtcp,
    serialize_rtcp,
)
from splitrender.protocol.errors import RtcpError
from splitrender.scene.pose import CameraIntrinsics
from splitrender.scene.pose import Pose as ScenePose
from splitrender.scene.trace import get_trace
from splitrender.transport.control import ControlChannel, wall_us
from splitrender.transport.errors import ConnectError, describe_os_error

__all__ = ["ClientConfig", "LiveClient", "ClientResult", "ServerRefusedError", "run_client"]

logger = logging.getLogger(__name__)

MAX_PENDING_FRAMES = 128
"""FrameMeta / decoded planes kept while waiting for their counterpart."""
MAX_READY_UPDATES = 16
"""Matched updates waiting for the display clock (oldest dropped beyond)."""
DECODE_QUEUE = 64
"""Access units waiting for the decoder; overflow flushes and asks for a keyframe."""
RTCP_TICK_S = 0.01
BIND_INTERVAL_S = 0.1


class ServerRefusedError(SplitRenderError):
    """The server answered with an ``Error`` message."""


@dataclass(frozen=True)
class ClientConfig:
    """Settings of a live client.  Times in seconds unless the name says ms.

    ``udp_port`` overrides the server UDP port from Welcome (to go through a relay).
    ``methods`` are offered in preference order.
    """

    server: str = "127.0.0.1"
    port: int = 9100
    udp_port: int | None = None
    token: str = ""
    methods: tuple[str, ...] = ("video",)
    codecs: tuple[str, ...] = ("h264", "hevc")
    width: int = 640
    height: int = 360
    display_hz: float = 60.0
    tracker_hz: float = 120.0
    trace: str = "walk"
    duration_s: float = 10.0
    out_dir: Path | None = None
    save_images: bool = False
    jitter_timeout_ms: float = 300.0
    nack_delay_ms: float = 20.0
    nack_retry_ms: float = 120.0
    nack_max_tries: int = 3
    pli_interval_ms: float = 250.0
    rr_interval_s: float = 0.5
    connect_timeout_s: float = 5.0


@dataclass
class _StreamRx:
    name: str
    codec: str
    ssrc: int
    jitter: JitterBuffer
    stats: ReceiverStatistics
    decoder: VideoDecoder
    output_format: str
    holes: dict[int, tuple[float, float, int]] = field(default_factory=dict)  # seq -> first seen, last nack, tries
    last_pli_ms: float = -math.inf
    first_packet_ms: float | None = None
    decode_broken: bool = False


@dataclass
class _Frame:
    """One update on its way: metadata, planes, per-stage wall-clock times (µs)."""

    frame_id: int
    meta: FrameMeta | None = None
    blob: dict[str, Any] | None = None
    meta_us: int = 0
    planes: dict[str, np.ndarray] = field(default_factory=dict)
    received_us: int = 0
    decoded_us: int = 0
    shown: bool = False


@dataclass
class ClientResult:
    """What a run recorded: per displayed frame rows, and session counters."""

    rows: list[dict[str, Any]]
    counters: dict[str, Any]
    recording: dict[str, Any]
    meta_frame_ids: list[int]
    out_dir: Path | None = None


class LiveClient:
    """One session against a live server; ``await LiveClient(cfg).run()``."""

    def __init__(self, config: ClientConfig) -> None:
        self.cfg = config
        self.trace = get_trace(config.trace)
        self.session_id = "?"
        self.gl_executor = concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix="sr-client-gl")
        self.decode_executor = concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix="sr-client-dec")
        self.io_executor = concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix="sr-client-io")
        self.channel: ControlChannel | None = None
        self.udp: asyncio.DatagramTransport | None = None
        self.streams: dict[str, _StreamRx] = {}
        self._by_ssrc: dict[int, _StreamRx] = {}
        self._frames: OrderedDict[int, _Frame] = OrderedDict()
        self._orphans: OrderedDict[tuple[str, int], tuple[np.ndarray, int, int]] = OrderedDict()
        self._ready: deque[_Frame] = deque()
        self._decode_q: asyncio.Queue[tuple[_StreamRx, AccessUnit, int]] = asyncio.Queue(DECODE_QUEUE)
        self._half: Any = None
        self._welcome: Welcome | None = None
        self._params: dict[str, Any] = {}
        self._server_epoch_s: float | None = None
        self._t0_wall = 0.0
        self._rtp_seen = False
        self._last_applied = -1
        self.rows: list[dict[str, Any]] = []
        self.meta_ids: list[int] = []
        self.counters: dict[str, Any] = {
            "rtp_packets": 0, "rtp_bytes": 0, "rtcp_sent": 0, "nacks_sent": 0, "nacked_packets": 0, "plis_sent": 0,
            "frames_meta": 0, "frames_complete": 0, "frames_displayed_updates": 0, "frames_skipped": 0,
            "decode_errors": 0, "decode_overflows": 0, "udp_bad": 0, "meta_bytes": 0, "late_ticks": 0,
            "updates_dropped_ready": 0, "keyframes_received": 0, "keyframes_after_pli": 0,
        }

    # ------------------------------------------------------------------ run

    async def run(self) -> ClientResult:
        """Connect, stream for ``duration_s``, say Bye, write the recording."""
        cfg = self.cfg
        try:
            try:
                reader, writer = await asyncio.wait_for(asyncio.open_connection(cfg.server, cfg.port),
                                                        cfg.connect_timeout_s)
            except (OSError, OverflowError) as exc:  # refused, unreachable, unknown host, timed out
                raise ConnectError(f"cannot connect to {cfg.server}:{cfg.port}: {describe_os_error(exc)}") from exc
            self.channel = ControlChannel(ClientConnection(), reader, writer, "client")
            try:
                await self._handshake()
                await self._open_udp()
                self._t0_wall = time.time()
                try:
                    async with asyncio.TaskGroup() as tg:
                        tg.create_task(self._pose_loop(), name="client-poses")
                        tg.create_task(self._control_loop(), name="client-control")
                        tg.create_task(self._rtcp_loop(), name="client-rtcp")
                        tg.create_task(self._decode_loop(), name="client-decode")
                        tg.create_task(self._display_loop(), name="client-display")
                except BaseExceptionGroup as eg:
                    _, rest = eg.split(_RunDone)
                    if rest is not None:  # re-raise the first real failure as itself
                        first: BaseException = rest
                        while isinstance(first, BaseExceptionGroup):
                            first = first.exceptions[0]
                        raise first from None
                await self._say_bye("duration reached")
            finally:
                if self.udp is not None:
                    self.udp.close()
                await self.channel.close()
        finally:
            await self._release()
        logger.info("session %s: client done: %d displayed rows, %s", self.session_id, len(self.rows),
                    ", ".join(f"{k}={v}" for k, v in self.counters.items() if v))
        result = ClientResult(self.rows, dict(self.counters), self._recording(), list(self.meta_ids), cfg.out_dir)
        if cfg.out_dir is not None:
            await asyncio.get_running_loop().run_in_executor(None, write_recording, result, cfg.out_dir)
        return result

    async def _release(self) -> None:
        loop = asyncio.get_running_loop()
        half, self._half = self._half, None
        if half is not None:
            try:
                await loop.run_in_executor(self.gl_executor, lambda: None)
            except RuntimeError:
                pass
        for ex in (self.gl_executor, self.decode_executor, self.io_executor):
            ex.shutdown(wait=True)

    async def _say_bye(self, reason: str) -> None:
        assert self.channel is not None
        try:
            await asyncio.wait_for(self.channel.send(Bye(reason)), 1.0)
        except (ConnectionError, asyncio.TimeoutError, SplitRenderError) as exc:
            logger.debug("session %s: Bye not sent: %s", self.session_id, exc)

    # ------------------------------------------------------------------ handshake

    async def _handshake(self) -> None:
        cfg, ch = self.cfg, self.channel
        assert ch is not None
        await ch.send(Hello(PROTOCOL_VERSION, cfg.token, tuple(cfg.methods), tuple(cfg.codecs), cfg.width,
                            cfg.height, float(cfg.display_hz)))
        msg = await asyncio.wait_for(ch.next_message(), cfg.connect_timeout_s)
        if isinstance(msg, Error):
            raise ServerRefusedError(f"server refused the session: {ControlChannel.error_message(msg)}")
        if not isinstance(msg, Welcome):
            raise ServerRefusedError(f"server closed the connection instead of answering Hello ({msg})")
        self._welcome = msg
        self.session_id = msg.session_id
        self._params = dict(msg.method_params)
        spec = get_method(msg.method)
        mcfg = make_config(spec.config, dict(self._params.get("config", {})))
        intr = CameraIntrinsics(cfg.width, cfg.height, float(self._params.get("fov_y_deg", 60.0)))
        blob = self._params.get("session_data", b"")
        session_data = unpack_meta(blob) if blob else {}

        def make_half() -> Any:
            from splitrender.render.gl import get_context

            return spec.client(mcfg, intr, get_context(), session_data)

        self._half = await asyncio.get_running_loop().run_in_executor(self.gl_executor, make_half)
        fmts = dict(self._params.get("stream_formats", {}))
        for s in msg.streams:
            fmt = fmts.get(s.name, "rgb24")
            rx = _StreamRx(s.name, s.codec, s.ssrc,
                           JitterBuffer(s.codec, frame_timeout_ms=cfg.jitter_timeout_ms),
                           ReceiverStatistics(s.ssrc), VideoDecoder(s.codec, fmt), fmt)  # type: ignore[arg-type]
            self.streams[s.name] = rx
            self._by_ssrc[s.ssrc] = rx
        logger.info("session %s: method %s, streams %s", self.session_id, msg.method,
                    ", ".join(f"{s.name}({s.codec}, ssrc {s.ssrc:08x})" for s in msg.streams))

    async def _open_udp(self) -> None:
        assert self._welcome is not None
        port = self.cfg.udp_port or (self._welcome.streams[0].port if self._welcome.streams else 0)
        loop = asyncio.get_running_loop()
        try:
            self.udp, _ = await loop.create_datagram_endpoint(lambda: _ClientUdp(self._on_datagram),
                                                              remote_addr=(self.cfg.server, port))
        except (OSError, OverflowError) as exc:
            raise ConnectError(f"cannot open udp to {self.cfg.server}:{port}: {describe_os_error(exc)}") from exc
        self._send_rtcp([ReceiverReport(0, tuple(ReportBlock(s.ssrc, 0, 0, 0, 0) for s in self.streams.values()))])

    # ------------------------------------------------------------------ poses

    async def _pose_loop(self) -> None:
        assert self.channel is not None
        interval = 1.0 / self.cfg.tracker_hz
        loop = asyncio.get_running_loop()
        start = loop.time()
        n = int(self.cfg.duration_s * self.cfg.tracker_hz) + 1
        for seq in range(n):
            delay = start + seq * interval - loop.time()
            if delay > 0:
                await asyncio.sleep(delay)
            now_us = wall_us()
            pose = self._trace_pose(now_us / 1e6)
            await self.channel.send(Pose(now_us, seq & 0xFFFFFFFF, tuple(float(v) for v in pose.position),  # type: ignore[arg-type]
                                         tuple(float(v) for v in pose.orientation)))  # type: ignore[arg-type]
        await asyncio.Event().wait()  # the display task ends the run

    def _trace_pose(self, wall_s: float) -> ScenePose:
        return self.trace.pose_at(min(max(0.0, wall_s - self._t0_wall), self.trace.duration_s))

    # ------------------------------------------------------------------ control

    async def _control_loop(self) -> None:
        assert self.channel is not None
        async for msg in self.channel.messages():
            if isinstance(msg, FrameMeta):
                self._on_meta(msg)
            elif isinstance(msg, Stats):
                logger.debug("session %s: server stats %s", self.session_id, dict(msg.counters))
            elif isinstance(msg, Bye):
                raise ServerRefusedError(f"server ended the session: {msg.reason}")
            elif isinstance(msg, Error):
                raise ServerRefusedError(f"server error {ControlChannel.error_message(msg)}")
        raise ConnectionResetError("server closed the control connection")

    def _on_meta(self, msg: FrameMeta) -> None:
        now = wall_us()
        self.counters["frames_meta"] += 1
        self.meta_ids.append(msg.frame_id)
        blob = msg.method_meta if isinstance(msg.method_meta, bytes) else b""
        self.counters["meta_bytes"] += len(blob)
        try:
            meta: dict[str, Any] = parse_update_envelope(unpack_meta(blob), "metadata")  # type: ignore[assignment]
        except CodecError as exc:  # MetaEnvelopeError is one too
            raise _BadMeta(f"FrameMeta {msg.frame_id}: {exc}") from exc
        # both stamps were taken at the same instant on the server's wall clock
        self._server_epoch_s = msg.server_time_us / 1e6 - float(meta.get("t_s", 0.0))
        fr = _Frame(msg.frame_id, msg, meta, now)
        self._frames[msg.frame_id] = fr
        while len(self._frames) > MAX_PENDING_FRAMES:
            self._frames.popitem(last=False)
        for name, ts in msg.rtp_timestamps.items():
            got = self._orphans.pop((name, ts), None)
            if got is not None:
                self._add_plane(fr, name, *got)
        self._check_complete(fr)

    # ------------------------------------------------------------------ UDP in

    def _on_datagram(self, data: bytes) -> None:
        now_ms = time.monotonic() * 1000
        if is_rtcp(data):
            try:
                for p in parse_rtcp(data):
                    if isinstance(p, SenderReport) and p.ssrc in self._by_ssrc:
                        self._by_ssrc[p.ssrc].stats.on_sender_report(p, now_ms)
            except RtcpError:
                self.counters["udp_bad"] += 1
            return
        try:
            pkt = RtpPacket.parse(data)
        except RtpError:
            self.counters["udp_bad"] += 1
            return
        rx = self._by_ssrc.get(pkt.ssrc)
        if rx is None:
            self.counters["udp_bad"] += 1
            return
        self._rtp_seen = True
        self.counters["rtp_packets"] += 1
        self.counters["rtp_bytes"] += len(data)
        rx.stats.receive(pkt, now_ms)
        if rx.first_packet_ms is None:
            rx.first_packet_ms = now_ms
        self._queue_units(rx, rx.jitter.insert(pkt, now_ms))

    def _queue_units(self, rx: _StreamRx, units: list[AccessUnit]) -> None:
        now = wall_us()
        for au in units:
            if au.keyframe:
                self.counters["keyframes_received"] += 1
                if self.counters["plis_sent"]:
                    self.counters["keyframes_after_pli"] += 1
                rx.decode_broken = False
            elif rx.decode_broken:
                continue
            try:
                self._decode_q.put_nowait((rx, au, now))
            except asyncio.QueueFull:
                self.counters["decode_overflows"] += 1
                while not self._decode_q.empty():
                    self._decode_q.get_nowait()
                for s in self.streams.values():
                    s.decode_broken = True

    # ------------------------------------------------------------------ decode

    async def _decode_loop(self) -> None:
        loop = asyncio.get_running_loop()
        while True:
            rx, au, received_us = await self._decode_q.get()
            if rx.decode_broken and not au.keyframe:
                continue
            try:
                plane = await loop.run_in_executor(self.decode_executor, rx.decoder.decode, au.data)
            except CodecError as exc:
                self.counters["decode_errors"] += 1
                rx.decode_broken = True
                logger.info("session %s: %s decode error, waiting for a keyframe: %s", self.session_id, rx.name, exc)
                continue
            decoded_us = wall_us()
            fid = self._frame_for(rx.name, au.timestamp)
            if fid is None:
                self._orphans[(rx.name, au.timestamp)] = (plane, received_us, decoded_us)
                while len(self._orphans) > MAX_PENDING_FRAMES:
                    self._orphans.popitem(last=False)
                continue
            fr = self._frames[fid]
            self._add_plane(fr, rx.name, plane, received_us, decoded_us)
            self._check_complete(fr)

    def _frame_for(self, name: str, ts: int) -> int | None:
        for fid in reversed(self._frames):
            fr = self._frames[fid]
            if fr.meta is not None and fr.meta.rtp_timestamps.get(name) == ts:
                return fid
        return None

    @staticmethod
    def _add_plane(fr: _Frame, name: str, plane: np.ndarray, received_us: int, decoded_us: int) -> None:
        fr.planes[name] = plane
        fr.received_us = max(fr.received_us, received_us)
        fr.decoded_us = max(fr.decoded_us, decoded_us)

    def _check_complete(self, fr: _Frame) -> None:
        assert fr.meta is not None
        if fr.frame_id <= self._last_applied or not all(n in fr.planes for n in fr.meta.rtp_timestamps):
            return
        # frames before this one that are still incomplete can never be shown in order
        for fid in [f for f in self._frames if f <= fr.frame_id]:
            if fid != fr.frame_id:
                self.counters["frames_skipped"] += 1
            del self._frames[fid]
        self._last_applied = fr.frame_id
        self.counters["frames_complete"] += 1
        self._ready.append(fr)
        while len(self._ready) > MAX_READY_UPDATES:
            self._ready.popleft()
            self.counters["updates_dropped_ready"] += 1

    # ------------------------------------------------------------------ RTCP out

    def _send_rtcp(self, packets: list[Any]) -> None:
        if self.udp is not None and not self.udp.is_closing():
            self.udp.sendto(serialize_rtcp(packets))
            self.counters["rtcp_sent"] += 1

    async def _rtcp_loop(self) -> None:
        cfg = self.cfg
        last_bind = last_rr = time.monotonic()
        while True:
            await asyncio.sleep(RTCP_TICK_S)
            now = time.monotonic()
            now_ms = now * 1000
            for rx in self.streams.values():
                self._queue_units(rx, rx.jitter.poll(now_ms))
            if not self._rtp_seen:
                if now - last_bind >= BIND_INTERVAL_S:
                    last_bind = now
                    self._send_rtcp([ReceiverReport(0, tuple(ReportBlock(s.ssrc, 0, 0, 0, 0)
                                                             for s in self.streams.values()))])
                continue
            out: list[Any] = []
            if now - last_rr >= cfg.rr_interval_s:
                last_rr = now
                out.append(ReceiverReport(0, tuple(s.stats.report_block(now_ms) for s in self.streams.values())))
            for rx in self.streams.values():
                nack = self._nack_list(rx, now_ms)
                if nack:
                    out.append(GenericNack(0, rx.ssrc, tuple(nack)))
                    self.counters["nacks_sent"] += 1
                    self.counters["nacked_packets"] += len(nack)
                started = rx.first_packet_ms is not None and now_ms - rx.first_packet_ms >= cfg.pli_interval_ms
                if ((rx.jitter.needs_keyframe and (started or rx.jitter.frames_emitted)) or rx.decode_broken) \
                        and now_ms - rx.last_pli_ms >= cfg.pli_interval_ms:
                    rx.last_pli_ms = now_ms
                    out.append(PictureLossIndication(0, rx.ssrc))
                    self.counters["plis_sent"] += 1
            if out:
                self._send_rtcp(out)

    def _nack_list(self, rx: _StreamRx, now_ms: float) -> list[int]:
        cfg = self.cfg
        missing = set(rx.jitter.missing())
        for seq in [s for s in rx.holes if s not in missing]:
            del rx.holes[seq]
        out = []
        for seq in missing:
            first, last, tries = rx.holes.get(seq, (now_ms, -math.inf, 0))
            if (tries < cfg.nack_max_tries and now_ms - first >= cfg.nack_delay_ms
                    and now_ms - last >= cfg.nack_retry_ms):
                out.append(seq)
                rx.holes[seq] = (first, now_ms, tries + 1)
            else:
                rx.holes.setdefault(seq, (first, last, tries))
        return out

    # ------------------------------------------------------------------ display

    async def _display_loop(self) -> None:
        cfg = self.cfg
        loop = asyncio.get_running_loop()
        interval = 1.0 / cfg.display_hz
        start = loop.time()
        n = int(cfg.duration_s * cfg.display_hz)
        half = self._half
        shown: _Frame | None = None
        saves: list[asyncio.Future[None]] = []
        for tick in range(n):
            delay = start + tick * interval - loop.time()
            if delay > 0:
                await asyncio.sleep(delay)
            elif delay < -interval:
                self.counters["late_ticks"] += 1
                continue  # more than a tick late: skip it rather than bunch renders up
            new = list(self._ready)
            self._ready.clear()
            if new:
                shown = new[-1]
            if shown is None or self._server_epoch_s is None:
                continue
            tick_wall = time.time()
            pose = self._trace_pose(tick_wall)
            trace_t = tick_wall - self._t0_wall
            scene_t = tick_wall - self._server_epoch_s
            updates = [DecodedUpdate(f.frame_id, float(f.blob["t_s"]), ScenePose.from_list(f.blob["pose"]),  # type: ignore[index]
                                     f.planes, f.blob["m"]) for f in new]  # type: ignore[index]

            def show() -> tuple[Any, float, float]:
                w0 = time.perf_counter()
                for u in updates:
                    try:
                        half.apply(u)
                    except RemoteProtocolError as exc:  # a malformed update: keep the last good state
                        self.counters["apply_errors"] = self.counters.get("apply_errors", 0) + 1
                        logger.warning("session %s: update %d rejected by the client half: %s", self.session_id, u.frame_id, exc)
                w1 = time.perf_counter()
                frame = half.render(pose, scene_t)
                return frame, (w1 - w0) * 1000, (time.perf_counter() - w1) * 1000

            cf, apply_ms, render_ms = await loop.run_in_executor(self.gl_executor, show)
            displayed_us = wall_us()
            row = self._row(len(self.rows), tick, trace_t, scene_t, pose, shown, displayed_us,
                            apply_ms + render_ms)
            row.update({f"cli_{k}": v for k, v in cf.stats.items()})
            self.rows.append(row)
            if cfg.save_images and cfg.out_dir is not None:
                idx = row["frame"]
                color, holes = cf.color, cf.holes
                saves.append(loop.run_in_executor(self.io_executor, _save_image, cfg.out_dir, idx, color, holes))
                if len(saves) > 64:
                    await asyncio.gather(*saves[:32])
                    del saves[:32]
            if not shown.shown:
                shown.shown = True
                self.counters["frames_displayed_updates"] += 1
                await self._feedback(shown, displayed_us)
        await asyncio.gather(*saves)
        raise _RunDone()

    def _row(self, index: int, tick: int, trace_t: float, scene_t: float, pose: ScenePose, fr: _Frame,
             displayed_us: int, client_ms: float) -> dict[str, Any]:
        assert fr.meta is not None and fr.blob is not None
        timing = fr.blob.get("timing_us", {})
        server_us = fr.meta.server_time_us
        encoded_at = int(timing.get("encoded_at", server_us))
        p = pose.to_list()
        row: dict[str, Any] = {
            "frame": index, "t_s": trace_t, "update_frame_id": fr.frame_id,
            "update_age_ms": (displayed_us - server_us) / 1000.0,
            "motion_to_photon_ms": (displayed_us - fr.meta.pose.client_time_us) / 1000.0,
            "client_ms": client_ms, "decode_ms": (fr.decoded_us - fr.received_us) / 1000.0,
            "tick": tick, "scene_t_s": scene_t, "displayed_us": displayed_us,
            "px": p[0], "py": p[1], "pz": p[2], "qx": p[3], "qy": p[4], "qz": p[5], "qw": p[6],
            "server_render_ms": timing.get("render", 0) / 1000.0, "server_encode_ms": timing.get("encode", 0) / 1000.0,
            "network_ms": (fr.received_us - encoded_at) / 1000.0,
            "meta_network_ms": (fr.meta_us - encoded_at) / 1000.0,
            "wait_display_ms": (displayed_us - fr.decoded_us) / 1000.0 - client_ms,
            "pose_uplink_age_ms": (server_us - fr.meta.pose.client_time_us) / 1000.0,
            "keyframe": int(fr.meta.keyframe),
        }
        return row

    async def _feedback(self, fr: _Frame, displayed_us: int) -> None:
        assert self.channel is not None and fr.meta is not None and fr.blob is not None
        timing = fr.blob.get("timing_us", {})
        server = {k: int(v) for k, v in timing.items() if k in ("render", "encode", "encoded_at")}
        await self.channel.send(Feedback(fr.frame_id, fr.received_us, fr.decoded_us, displayed_us, 0,
                                         fr.meta.pose.client_time_us, server))

    # ------------------------------------------------------------------ recording

    def _recording(self) -> dict[str, Any]:
        cfg = self.cfg
        w = self._welcome
        return {
            "session_id": self.session_id, "method": w.method if w else "", "params": self._params.get("config", {}),
            "scene": self._params.get("scene", "default"), "fov_y_deg": self._params.get("fov_y_deg", 60.0),
            "server_fps": self._params.get("server_fps", 30), "trace": cfg.trace, "width": cfg.width,
            "height": cfg.height, "display_hz": cfg.display_hz, "tracker_hz": cfg.tracker_hz,
            "duration_s": cfg.duration_s, "images": bool(cfg.save_images and cfg.out_dir is not None),
            "client": {k: (str(v) if isinstance(v, Path) else v) for k, v in asdict(cfg).items()},
        }


class _RunDone(Exception):
    """The display clock reached ``duration_s``."""


class _BadMeta(RemoteProtocolError):
    """FrameMeta.meta could not be unpacked."""


class _ClientUdp(asyncio.DatagramProtocol):
    def __init__(self, on_datagram: Any) -> None:
        self._on_datagram = on_datagram

    def datagram_received(self, data: bytes, addr: Any) -> None:
        self._on_datagram(data)

    def error_received(self, exc: Exception) -> None:
        logger.debug("client udp error: %s", exc)


def _save_image(out_dir: Path, index: int, color: np.ndarray, holes: np.ndarray | None) -> None:
    d = out_dir / "images"
    d.mkdir(parents=True, exist_ok=True)
    arrays: dict[str, np.ndarray] = {"color": color}
    if holes is not None:
        arrays["holes"] = holes
    np.savez_compressed(d / f"{index:06d}.npz", **arrays)  # type: ignore[arg-type]


def write_recording(result: ClientResult, out_dir: Path) -> None:
    """frames.csv (per displayed frame, unscored), recording.json and counters.json."""
    from splitrender.sim.runner import write_csv

    out_dir.mkdir(parents=True, exist_ok=True)
    write_csv(out_dir / "frames.csv", result.rows)
    (out_dir / "recording.json").write_text(json.dumps(result.recording, indent=2, default=str))
    (out_dir / "counters.json").write_text(json.dumps(result.counters, indent=2))


async def run_client(config: ClientConfig) -> ClientResult:
    """Run one live client session (see :class:`LiveClient`)."""
    return await LiveClient(config).run()
