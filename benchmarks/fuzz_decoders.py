"""Mutation fuzzing of every untrusted-input entry point, from valid seeds.

Each entry point gets real seeds (H.264/HEVC access units from the encoder, RTP packets
with a sequence wrap, RTCP compounds, SDP, every control message framed, ``warp`` and
``sas`` metadata blobs, BC4 depth) and is fed ``N`` inputs made by 1-3 mutations each:
bit flips, interesting bytes, truncation, splices with another seed, length-field
inflation (1/2/4/8-byte fields set to huge values, big- and little-endian), chunk
insertion, deletion and duplication.  Metadata entry points are fuzzed at both layers:
the zstd frame as sent, and the msgpack inside, recompressed with or without a declared
content size.

The rule (h11's): an input either decodes or raises the entry point's documented error
class.  Anything else is reported with a minimal reproducer (greedy chunk deletion that
keeps the exception type), in hex.  Also reported: inputs per second of wall time and
of this process's CPU time (the one to compare on a shared machine), worst time per input (as
measured, and the slowest 20 inputs re-timed best-of-3, since one timing on a shared
machine includes preemption; with that input), and the peak RSS during the entry
point's run above the RSS at its start (the peak mark is reset through
``/proc/self/clear_refs`` on Linux).

Run: ``python benchmarks/fuzz_decoders.py [--inputs N] [--slow-inputs M] [--only a,b]``.
Writes ``benchmarks/results/fuzz_decoders.json``.
"""

from __future__ import annotations

import argparse
import heapq
import json
import logging
import platform
import random
import resource
import struct
import sys
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import msgpack
import numpy as np
import zstandard

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout

from splitrender.codecs.depth import bc4_decode, bc4_encode, quantize_depth  # noqa: E402
from splitrender.codecs.meta import pack_meta, parse_update_envelope, unpack_meta  # noqa: E402
from splitrender.errors import CodecError, RemoteProtocolError  # noqa: E402
from splitrender.protocol import (  # noqa: E402
    NEED_DATA,
    Bye,
    ClientConnection,
    Error,
    Feedback,
    FrameMeta,
    GenericNack,
    Hello,
    JitterBuffer,
    KeyframeRequest,
    PictureLossIndication,
    Pose,
    ReceiverReport,
    ReportBlock,
    RtpPacket,
    RtpPacketizer,
    SenderReport,
    ServerConnection,
    Stats,
    StreamDescription,
    Welcome,
    encode_frame,
    h264_depayload,
    h265_depayload,
    make_sdp,
    parameter_sets_from_sdp,
    parse_fmtp,
    parse_rtcp,
    serialize_rtcp,
)
from splitrender.protocol.messages import PROTOCOL_VERSION  # noqa: E402

logger = logging.getLogger("fuzz_decoders")
RESULTS = Path(__file__).resolve().parent / "results" / "fuzz_decoders.json"
W, H = 64, 36
HEX_MAX = 4096  # hex characters of a reproducer kept in the report
MINIMIZE_TRIES = 3000
SLOWEST_KEPT = 20
"""The slowest inputs are timed again after the run (best of 3): on a shared machine a
single timing includes preemption, so the re-timed worst is the number to trust."""


# ---------------------------------------------------------------------------- mutation
INTERESTING_BYTES = (0x00, 0x01, 0x7F, 0x80, 0xFF, 0xC1, 0xDD, 0xDF, 0xC6, 0xC9)
INFLATE_VALUES = (2**7, 2**8 - 1, 2**15, 2**16 - 1, 2**31 - 1, 2**31, 2**32 - 1, 2**40, 2**63 - 1, 2**63, 2**64 - 1)


def mutate(data: bytes, seeds: list[bytes], rng: random.Random) -> bytes:
    """1-3 random mutations of ``data`` (see the module docstring)."""
    b = bytearray(data)
    for _ in range(rng.randint(1, 3)):
        op = rng.randrange(8)
        n = len(b)
        if op == 0 and n:  # bit flips
            for _ in range(rng.randint(1, 8)):
                i = rng.randrange(n * 8)
                b[i // 8] ^= 1 << (i % 8)
        elif op == 1 and n:  # interesting bytes
            for _ in range(rng.randint(1, 4)):
                b[rng.randrange(n)] = rng.choice(INTERESTING_BYTES)
        elif op == 2:  # truncation
            del b[rng.randint(0, n):]
        elif op == 3:  # splice with another seed
            other = rng.choice(seeds)
            i, j = sorted((rng.randint(0, len(other)), rng.randint(0, len(other))))
            k = rng.randint(0, n)
            b[k:rng.randint(k, n)] = other[i:j]
        elif op == 4 and n:  # length-field inflation
            width = rng.choice((1, 2, 4, 8))
            pos = rng.randint(0, max(0, n - width))
            v = rng.choice(INFLATE_VALUES) & ((1 << (8 * width)) - 1)
            b[pos:pos + width] = v.to_bytes(width, rng.choice(("big", "little")))
        elif op == 5:  # insert random bytes
            k = rng.randint(0, n)
            b[k:k] = bytes(rng.randrange(256) for _ in range(rng.randint(1, 16)))
        elif op == 6 and n:  # delete a chunk
            i = rng.randrange(n)
            del b[i:i + rng.randint(1, 32)]
        elif op == 7 and n:  # duplicate a chunk
            i = rng.randrange(n)
            j = min(n, i + rng.randint(1, 64))
            b[j:j] = b[i:j] * rng.randint(1, 4)
    return bytes(b)


# ---------------------------------------------------------------------------- entry points
@dataclass
class EntryPoint:
    """``run(data)`` decodes one input; ``expected`` is what it may raise."""

    name: str
    seeds: list[bytes]
    run: Callable[[bytes], Any]
    expected: tuple[type[BaseException], ...]
    slow: bool = False
    encode: Callable[[bytes, random.Random], bytes] | None = None
    """Applied after mutating (the msgpack layer is mutated, then compressed)."""


def _zstd_either(raw: bytes, rng: random.Random) -> bytes:
    """zstd with a declared content size, or without (the streaming path)."""
    return zstandard.ZstdCompressor(level=1, write_content_size=rng.random() < 0.7).compress(raw)


def _split_lp(data: bytes) -> list[bytes]:
    """Inverse of :func:`_join_lp`: 2-byte big-endian length-prefixed chunks (stops at a short one)."""
    out, pos = [], 0
    while pos + 2 <= len(data):
        (n,) = struct.unpack_from(">H", data, pos)
        out.append(data[pos + 2:pos + 2 + n])
        pos += 2 + n
    return out


def _join_lp(chunks: list[bytes]) -> bytes:
    return b"".join(struct.pack(">H", len(c)) + c for c in chunks)


def _encode_aus(codec: str, n: int = 6) -> list[bytes]:
    from splitrender.codecs.video import VideoCodecConfig, VideoEncoder

    enc = VideoEncoder(VideoCodecConfig(codec=codec, gop=3), W, H)  # type: ignore[arg-type]
    rng = np.random.default_rng(1)
    img = rng.integers(0, 256, (H, W * 2, 3), dtype=np.uint8)
    aus = []
    for i in range(n):
        ef = enc.encode(np.ascontiguousarray(img[:, 4 * i:4 * i + W]), force_idr=i == 0)
        aus.append(bytes(ef.data))
    return [a for a in aus if a]


def _warp_seed() -> tuple[bytes, Callable[[bytes], Any]]:
    from splitrender.methods.base import DecodedUpdate
    from splitrender.methods.warp import META_VERSION, WarpConfig, parse_update
    from splitrender.scene.pose import CameraIntrinsics
    from splitrender.scene.pose import Pose as ScenePose

    intr = CameraIntrinsics(W, H, 60.0)
    cfg = WarpConfig(views=1, depth_coding="bc4")
    pose = [0.0, 1.6, 2.5, 0.0, 0.0, 0.0, 1.0]
    depth = np.linspace(1.0, 20.0, W * H).reshape(H, W)
    depth[:4] = np.inf
    m = {"v": META_VERSION, "depth_coding": "bc4", "depth_near_m": 0.1, "ref": [W, H, 60.0],
         "views": [{"pose": pose, "ids": (np.arange(W * H) % 3).reshape(H, W).astype(np.uint8),
                    "bc4": bc4_encode(quantize_depth(depth, 0.1))}],
         "obj_ids": np.array([1, 2], np.uint16), "obj_model": np.tile(np.eye(4), (2, 1, 1)),
         "dyn_ids": np.array([2], np.uint16), "dyn_prev": np.eye(4)[None], "dt_s": 1 / 30}
    blob = pack_meta({"t_s": 1.0, "pose": pose, "m": m, "target_t_s": 1.05,
                      "timing_us": {"render": 900, "encode": 700, "encoded_at": 1_700_000_000_000_000},
                      "srv": {"views": 1.0, "objects": 2.0, "bc4_bytes": 300.0}})
    color = np.zeros((H, W, 3), np.uint8)

    def run(data: bytes) -> Any:
        env = parse_update_envelope(unpack_meta(data))
        return parse_update(DecodedUpdate(0, env["t_s"], ScenePose.from_list(env["pose"]), {"color0": color},
                                          env["m"]), cfg, intr)

    run(blob)
    return blob, run


def _sas_seeds() -> tuple[bytes, bytes, Callable[[bytes], Any], Callable[[bytes], Any]]:
    from splitrender.methods.sas.wire import META_VERSION, parse_frame_meta, parse_session

    # seeds from a real sas session (wire v3): a short virtual-time run, envelopes captured as packed
    from splitrender.pipeline import sender as pipeline_wire
    from splitrender.sim.config import RunConfig
    from splitrender.sim.runner import VirtualTimeRun

    blobs: list[bytes] = []
    real = pipeline_wire.pack_envelope

    def capture(env: Any) -> bytes:
        out = real(env)
        blobs.append(out)
        return out

    pipeline_wire.pack_envelope = capture
    try:
        vt = VirtualTimeRun(RunConfig(method="sas", scene="minimal", trace="walk", network="ideal", width=160, height=90,
                                      duration_s=0.2, client_fps=30, metrics=False))
        vt.run()
    finally:
        pipeline_wire.pack_envelope = real
    sd = vt.clients[0].half.session_data()
    session = parse_session(sd)
    frame_blob = blobs[0]
    session_blob = pack_meta(sd)
    assert META_VERSION == parse_update_envelope(unpack_meta(frame_blob))["m"]["v"]

    def run_frame(data: bytes) -> Any:
        return parse_frame_meta(parse_update_envelope(unpack_meta(data))["m"], session)

    def run_session(data: bytes) -> Any:
        return parse_session(unpack_meta(data))

    run_frame(frame_blob)
    run_session(session_blob)
    return frame_blob, session_blob, run_frame, run_session


def _control_seeds() -> list[bytes]:
    pose = Pose(1_700_000_000_000_000, 7, (0.0, 1.6, 2.5), (0.0, 0.0, 0.0, 1.0))
    meta = FrameMeta(5, 1_700_000_000_000_000, {"color": 123456}, pose, pack_meta({"t_s": 1.0, "m": {}}), True)
    welcome = Welcome("sid-1", "warp", {"config": {"views": 2}, "session_data": b"\x00" * 40},
                      (StreamDescription("color", "h264", 0x1234, 96, 5004, make_sdp("h264", 5004, 96)),))
    msgs: list[Any] = [Hello(PROTOCOL_VERSION, "tok", ("warp", "video"), ("h264", "hevc"), 640, 360, 60.0),
                       welcome, pose, meta, Feedback(5, 1, 2, 3, 0, 4, {"render": 1}), KeyframeRequest("color", "loss"),
                       Stats({"fps": 60.0, "lost": 0}), Bye("done"), Error(400, "x" * 1500)]
    frames = [encode_frame(m) for m in msgs]
    frames.append(encode_frame(meta, compress=True))
    frames.append(b"".join(frames[2:5]))  # a stream of several frames
    return frames


def _connection_run(role: str) -> Callable[[bytes], Any]:
    """Feed bytes to a Connection already in STREAMING; on a peer error send an Error."""
    hello = Hello(PROTOCOL_VERSION, "", ("video",), ("h264",), 160, 90, 30.0)

    def run(data: bytes) -> Any:
        c, s = ClientConnection(), ServerConnection()
        s.receive_data(c.send(hello))
        s.next_event()
        c.receive_data(s.send(Welcome("sid", "video")))
        c.next_event()
        conn = c if role == "client" else s
        try:
            step = 1 + len(data) % 97
            for i in range(0, len(data), step):
                conn.receive_data(data[i:i + step])
                while conn.next_event() is not NEED_DATA:
                    pass
            conn.receive_data(b"")
            conn.next_event()
        except RemoteProtocolError as exc:
            conn.send_error(exc)  # must work in every state peer input can reach
            raise

    return run


def _rtp_seeds(codec: str, aus: list[bytes]) -> list[bytes]:
    pk = RtpPacketizer(codec, 0x1234ABCD, 96, mtu=300, first_sequence=65530)  # type: ignore[arg-type]
    return [bytes(p) for i, au in enumerate(aus) for p in pk.packetize(au, i * 3000)]


def _jitter_run(codec: str) -> Callable[[bytes], Any]:
    def run(data: bytes) -> Any:
        jb = JitterBuffer(codec, max_packets=128)  # type: ignore[arg-type]
        now = 0.0
        for raw in _split_lp(data):
            now += 3.0
            try:
                pkt = RtpPacket.parse(raw)
            except RemoteProtocolError:
                continue
            jb.insert(pkt, now)  # malformed payloads are counted, never raised
        jb.poll(now + 1000.0)
        jb.missing()

    return run


def _video_run(codec: str) -> Callable[[bytes], Any]:
    from splitrender.codecs.video import VideoDecoder

    def run(data: bytes) -> Any:
        dec = VideoDecoder(codec, "rgb24")  # type: ignore[arg-type]
        return dec.decode(data)

    return run


def build_entry_points() -> list[EntryPoint]:
    """Seeds and decoders of every untrusted-input entry point."""
    aus = {c: _encode_aus(c) for c in ("h264", "hevc")}
    rtp = {c: _rtp_seeds(c, aus[c]) for c in aus}
    warp_blob, warp_run = _warp_seed()
    sas_frame, sas_session, sas_frame_run, sas_session_run = _sas_seeds()
    meta_blobs = [warp_blob, sas_frame, sas_session, pack_meta({"t_s": 0.0, "pose": [0, 0, 0, 0, 0, 0, 1], "m": {}})]
    raw_meta = [zstandard.ZstdDecompressor().decompress(b) for b in meta_blobs]
    bc4 = bc4_encode(quantize_depth(np.linspace(0.5, 30, W * H).reshape(H, W), 0.1))
    sr = SenderReport(0x1234ABCD, 0xE0000000_00000000, 90000, 10, 5000)
    rtcp = [serialize_rtcp([sr]), serialize_rtcp([ReceiverReport(1, (ReportBlock(0x1234ABCD, 3, 10, 2, 300),)),
                                                  GenericNack(1, 0x1234ABCD, (65534, 65535, 0, 1, 17)),
                                                  PictureLossIndication(1, 0x1234ABCD)])]
    sdp = [make_sdp(c, 5004, 96, parameter_sets=ps).encode() for c, ps in
           (("h264", [b"\x67\x42\x00\x1e\xab\xcd", b"\x68\xce\x3c\x80"]),
            ("hevc", [b"\x40\x01\x0c\x01", b"\x42\x01\x01\x01", b"\x44\x01\xc1\x72"]))]
    control = _control_seeds()

    def payloads(codec: str) -> list[bytes]:
        per_au: dict[int, list[bytes]] = {}
        for raw in rtp[codec]:
            p = RtpPacket.parse(raw)
            per_au.setdefault(p.timestamp, []).append(p.payload)
        return [_join_lp(v) for v in per_au.values()]

    def sdp_run(data: bytes) -> Any:
        text = data.decode("utf-8", "replace")
        parse_fmtp(text)
        return parameter_sets_from_sdp(text)

    return [
        EntryPoint("unpack_meta.zstd", meta_blobs, lambda d: parse_update_envelope(unpack_meta(d)), (CodecError,)),
        EntryPoint("unpack_meta.msgpack", raw_meta, lambda d: parse_update_envelope(unpack_meta(d)), (CodecError,),
                   encode=_zstd_either),
        EntryPoint("warp.parse_update", [warp_blob], warp_run, (CodecError,)),
        EntryPoint("warp.parse_update.msgpack", [raw_meta[0]], warp_run, (CodecError,), encode=_zstd_either),
        EntryPoint("sas.parse_frame_meta", [sas_frame], sas_frame_run, (CodecError, RemoteProtocolError)),
        EntryPoint("sas.parse_frame_meta.msgpack", [raw_meta[1]], sas_frame_run, (CodecError, RemoteProtocolError),
                   encode=_zstd_either),
        EntryPoint("sas.parse_session.msgpack", [raw_meta[2]], sas_session_run, (CodecError, RemoteProtocolError),
                   encode=_zstd_either),
        EntryPoint("bc4_decode", [bc4], bc4_decode, (CodecError,)),
        EntryPoint("connection.client", control, _connection_run("client"), (RemoteProtocolError,)),
        EntryPoint("connection.server", control, _connection_run("server"), (RemoteProtocolError,)),
        EntryPoint("rtp.parse", rtp["h264"] + rtp["hevc"], RtpPacket.parse, (RemoteProtocolError,)),
        EntryPoint("rtcp.parse", rtcp, parse_rtcp, (RemoteProtocolError,)),
        EntryPoint("h264_depayload", payloads("h264"), lambda d: h264_depayload(_split_lp(d)), (RemoteProtocolError,)),
        EntryPoint("h265_depayload", payloads("hevc"), lambda d: h265_depayload(_split_lp(d)), (RemoteProtocolError,)),
        EntryPoint("jitter.h264", [_join_lp(rtp["h264"])], _jitter_run("h264"), ()),
        EntryPoint("jitter.hevc", [_join_lp(rtp["hevc"])], _jitter_run("hevc"), ()),
        EntryPoint("sdp", sdp, sdp_run, (RemoteProtocolError,)),
        EntryPoint("video.h264", aus["h264"], _video_run("h264"), (CodecError,), slow=True),
        EntryPoint("video.hevc", aus["hevc"], _video_run("hevc"), (CodecError,), slow=True),
    ]


# ---------------------------------------------------------------------------- running
@dataclass
class Finding:
    type: str
    message: str
    count: int = 0
    smallest: bytes = b""
    where: str = ""


@dataclass
class Report:
    name: str
    inputs: int = 0
    seconds: float = 0.0
    cpu_seconds: float = 0.0
    decoded: int = 0
    expected_errors: dict[str, int] = field(default_factory=dict)
    unexpected: dict[str, Finding] = field(default_factory=dict)
    worst_s: float = 0.0
    worst_input: bytes = b""
    worst_rerun_s: float = 0.0
    worst_rerun_input: bytes = b""
    maxrss_growth_mb: float = 0.0


def _status_mb(key: str) -> float | None:
    """``VmHWM`` (peak RSS) or ``VmRSS`` of this process in MB, from /proc (Linux)."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith(key + ":"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return None


def _reset_peak_rss() -> bool:
    """Reset the peak-RSS mark (``echo 5 > /proc/self/clear_refs``, Linux 4.0+)."""
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        return True
    except OSError:
        return False


def _maxrss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # Linux: kB


def _peak_growth_start() -> tuple[bool, float]:
    """(whether the /proc peak mark was reset, the baseline MB to subtract later)."""
    if _reset_peak_rss() and _status_mb("VmRSS") is not None:
        return True, float(_status_mb("VmRSS"))  # type: ignore[arg-type]
    return False, _maxrss_mb()


def _peak_growth_end(start: tuple[bool, float]) -> float:
    """Peak RSS since :func:`_peak_growth_start` minus the RSS then (MB); without /proc,
    the growth of the process's lifetime peak (which hides growth below an earlier peak)."""
    reset, base = start
    peak = _status_mb("VmHWM") if reset else None
    return (peak if peak is not None else _maxrss_mb()) - base


def _raises(ep: EntryPoint, data: bytes) -> str | None:
    try:
        ep.run(data)
    except ep.expected:
        return None
    except Exception as exc:  # noqa: BLE001 - that is what we look for
        return type(exc).__name__
    return None


def _timed(ep: EntryPoint, data: bytes) -> float:
    t0 = time.perf_counter()
    try:
        ep.run(data)
    except Exception:  # noqa: BLE001 - timing only
        pass
    return time.perf_counter() - t0


def minimize(ep: EntryPoint, data: bytes, exc_type: str) -> bytes:
    """Greedy chunk deletion that keeps ``exc_type`` raised (at most :data:`MINIMIZE_TRIES` runs)."""
    tries = 0
    chunk = max(1, len(data) // 2)
    while chunk >= 1 and tries < MINIMIZE_TRIES:
        i, shrunk = 0, False
        while i < len(data) and tries < MINIMIZE_TRIES:
            cand = data[:i] + data[i + chunk:]
            tries += 1
            if _raises(ep, cand) == exc_type:
                data, shrunk = cand, True
            else:
                i += chunk
        if not shrunk:
            chunk //= 2
    return data


def fuzz(ep: EntryPoint, n: int, seed: int) -> Report:
    rng = random.Random(f"{seed}:{ep.name}")
    rep = Report(ep.name)
    rss0 = _peak_growth_start()
    cpu_start = time.process_time()
    t_start = time.perf_counter()
    last_log = t_start
    slowest: list[tuple[float, int, bytes]] = []  # min-heap of the SLOWEST_KEPT slowest
    for k in range(n):
        base = rng.choice(ep.seeds)
        data = mutate(base, ep.seeds, rng)
        if ep.encode is not None:
            data = ep.encode(data, rng)
        t0 = time.perf_counter()
        try:
            ep.run(data)
            rep.decoded += 1
        except ep.expected as exc:
            name = type(exc).__name__
            rep.expected_errors[name] = rep.expected_errors.get(name, 0) + 1
        except Exception as exc:  # noqa: BLE001
            name = type(exc).__name__
            f = rep.unexpected.get(name)
            if f is None:
                tb = traceback.extract_tb(exc.__traceback__)[-1]
                f = rep.unexpected[name] = Finding(name, str(exc)[:300], 0, data, f"{tb.filename}:{tb.lineno}")
            f.count += 1
            if len(data) < len(f.smallest):
                f.smallest = data
        dt = time.perf_counter() - t0
        if dt > rep.worst_s:
            rep.worst_s, rep.worst_input = dt, data
        if len(slowest) < SLOWEST_KEPT:
            heapq.heappush(slowest, (dt, k, data))
        elif dt > slowest[0][0]:
            heapq.heapreplace(slowest, (dt, k, data))
        now = time.perf_counter()
        if now - last_log > 30:
            last_log = now
            logger.info("%s: %d/%d inputs, %.0f/s", ep.name, k + 1, n, (k + 1) / (now - t_start))
    rep.inputs = n
    rep.seconds = time.perf_counter() - t_start
    rep.cpu_seconds = time.process_time() - cpu_start
    rep.maxrss_growth_mb = _peak_growth_end(rss0)
    for _, _, data in slowest:
        best = min(_timed(ep, data) for _ in range(3))
        if best >= rep.worst_rerun_s:
            rep.worst_rerun_s, rep.worst_rerun_input = best, data
    for name, f in rep.unexpected.items():
        if ep.encode is None:  # a reproducer of the raw input (encoded inputs are reported as fed)
            f.smallest = minimize(ep, f.smallest, name)
    return rep


def _as_json(rep: Report) -> dict[str, Any]:
    return {
        "inputs": rep.inputs, "seconds": round(rep.seconds, 2), "cpu_seconds": round(rep.cpu_seconds, 2),
        "inputs_per_s": round(rep.inputs / rep.seconds, 1) if rep.seconds else None,
        "inputs_per_cpu_s": round(rep.inputs / rep.cpu_seconds, 1) if rep.cpu_seconds else None,
        "decoded": rep.decoded, "expected_errors": dict(sorted(rep.expected_errors.items())),
        "unexpected": {k: {"count": f.count, "message": f.message, "raised_at": f.where,
                           "reproducer_hex": f.smallest.hex()[:HEX_MAX], "reproducer_len": len(f.smallest)}
                       for k, f in rep.unexpected.items()},
        "worst_ms": round(rep.worst_s * 1000, 3), "worst_input_len": len(rep.worst_input),
        "worst_ms_retimed": round(rep.worst_rerun_s * 1000, 3),
        "worst_retimed_input_len": len(rep.worst_rerun_input),
        "worst_retimed_input_hex": rep.worst_rerun_input.hex()[:HEX_MAX],
        "peak_rss_growth_mb": round(rep.maxrss_growth_mb, 1),
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--inputs", type=int, default=100_000, help="inputs per fast entry point")
    ap.add_argument("--slow-inputs", type=int, default=2_000, help="inputs per slow entry point (video decoders)")
    ap.add_argument("--only", default="", help="comma-separated entry point names (prefixes)")
    ap.add_argument("--seed", type=int, default=16)
    ap.add_argument("--out", type=Path, default=RESULTS)
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    logging.getLogger("splitrender").setLevel(logging.CRITICAL)  # the decoders log every bad input
    eps = build_entry_points()
    if args.only:
        wanted = tuple(args.only.split(","))
        eps = [e for e in eps if e.name.startswith(wanted)]
    results: dict[str, Any] = {}
    for ep in eps:
        n = args.slow_inputs if ep.slow else args.inputs
        rep = fuzz(ep, n, args.seed)
        results[ep.name] = _as_json(rep)
        r = results[ep.name]
        logger.info("%-30s %7d inputs %7.0f/s (%7.0f per CPU s)  worst %8.2f ms (re-timed %.2f ms)  peak RSS +%.1f MB  unexpected %s",
                    ep.name, n, r["inputs_per_s"] or 0, r["inputs_per_cpu_s"] or 0, r["worst_ms"], r["worst_ms_retimed"], r["peak_rss_growth_mb"],
                    {k: v["count"] for k, v in r["unexpected"].items()} or "none")
    out = {
        "machine": {"python": platform.python_version(), "platform": platform.platform(),
                    "zstandard": zstandard.__version__, "msgpack": ".".join(map(str, msgpack.version))},
        "args": {"inputs": args.inputs, "slow_inputs": args.slow_inputs, "seed": args.seed},
        "peak_rss_mb": round(_maxrss_mb(), 1),
        "unexpected_total": sum(len(r["unexpected"]) for r in results.values()),
        "entry_points": results,
    }
    if not args.only:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(out, indent=2) + "\n")
        logger.info("wrote %s", args.out)
    else:
        print(json.dumps(out, indent=2))
    return 1 if out["unexpected_total"] else 0


if __name__ == "__main__":
    raise SystemExit(main())
