"""RTP packetizer/depacketizer throughput on real 1280x720 H.264 and HEVC frames.

Compares splitrender.protocol's payload formats with aiortc's own H.264 payloader
(``H264Encoder._split_bitstream`` + ``_packetize``) and depayloader
(``H264PayloadDescriptor.parse``), measured in the same run with the same packet size
(aiortc's fixed PACKET_MAX).  Writes ``benchmarks/results/bench_rtp.json``.

Run: ``python benchmarks/bench_rtp.py [--frames N] [--seconds S]``.
"""

from __future__ import annotations

import argparse
import json
import logging
import platform
import sys
import time
from collections.abc import Callable
from fractions import Fraction
from pathlib import Path

import av
import numpy as np
from aiortc.codecs import h264 as aiortc_h264

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout

from splitrender.protocol import RtpPacketizer, depacketize, payloads_for

logger = logging.getLogger("bench_rtp")

WIDTH, HEIGHT, FPS = 1280, 720, 30
BITRATE_BPS = 8_000_000
RESULTS = Path(__file__).resolve().parent / "results" / "bench_rtp.json"
ENCODERS = {"h264": "libx264", "hevc": "libx265"}


def encode_frames(codec: str, n_frames: int, seed: int = 0) -> list[bytes]:
    """Annex-B access units of a moving, textured 1280x720 test sequence."""
    rng = np.random.default_rng(seed)
    texture = rng.integers(0, 256, (HEIGHT, WIDTH * 2, 3), dtype=np.uint8)
    ctx = av.CodecContext.create(ENCODERS[codec], "w")
    ctx.width, ctx.height, ctx.pix_fmt = WIDTH, HEIGHT, "yuv420p"
    ctx.time_base = Fraction(1, FPS)
    ctx.framerate = Fraction(FPS, 1)
    ctx.bit_rate = BITRATE_BPS
    ctx.max_b_frames = 0
    ctx.gop_size = 30
    opts = {"tune": "zerolatency", "preset": "ultrafast"}
    if codec == "hevc":
        opts["x265-params"] = "bframes=0:log-level=error"
    ctx.options = opts
    aus: list[bytes] = []
    for i in range(n_frames):
        img = np.ascontiguousarray(texture[:, 8 * i : 8 * i + WIDTH])
        frame = av.VideoFrame.from_ndarray(img, format="rgb24").reformat(format="yuv420p")
        frame.pts = i
        aus.extend(bytes(p) for p in ctx.encode(frame))
    aus.extend(bytes(p) for p in ctx.encode(None))
    return aus


def measure(fn: Callable[[], int], nbytes: int, seconds: float) -> dict[str, float]:
    """Run ``fn`` (returns packet count) repeatedly for about ``seconds``."""
    fn()  # warm-up
    reps, packets = 0, 0
    start = time.perf_counter()
    while True:
        packets += fn()
        reps += 1
        elapsed = time.perf_counter() - start
        if elapsed >= seconds:
            break
    return {
        "MB_per_s": nbytes * reps / elapsed / 1e6,
        "packets_per_s": packets / elapsed,
        "repetitions": reps,
    }


def bench_codec(codec: str, aus: list[bytes], mtu: int, seconds: float) -> dict[str, object]:
    nbytes = sum(len(a) for a in aus)
    payloads = [payloads_for(codec, a, mtu) for a in aus]
    packetizer = RtpPacketizer(codec, ssrc=1, payload_type=96, mtu=mtu)

    def ours_payloads() -> int:
        return sum(len(payloads_for(codec, a, mtu)) for a in aus)

    def ours_packets() -> int:
        n = 0
        for i, a in enumerate(aus):
            for p in packetizer.packetize(a, i * 3000):
                bytes(p)
                n += 1
        return n

    def ours_depay() -> int:
        for ps in payloads:
            depacketize(codec, ps)
        return sum(len(ps) for ps in payloads)

    result: dict[str, object] = {
        "frames": len(aus),
        "bytes": nbytes,
        "packets": sum(len(p) for p in payloads),
        "ours": {
            "packetize": measure(ours_payloads, nbytes, seconds),
            "packetize_rtp_serialized": measure(ours_packets, nbytes, seconds),
            "depacketize": measure(ours_depay, nbytes, seconds),
        },
    }
    if codec == "h264":
        enc = aiortc_h264.H264Encoder
        theirs_payloads = [enc._packetize(enc._split_bitstream(a)) for a in aus]

        def aiortc_pay() -> int:
            return sum(len(enc._packetize(enc._split_bitstream(a))) for a in aus)

        def aiortc_depay() -> int:
            for ps in theirs_payloads:
                b"".join(aiortc_h264.H264PayloadDescriptor.parse(p)[1] for p in ps)
            return sum(len(ps) for ps in theirs_payloads)

        theirs = {
            "packetize": measure(aiortc_pay, nbytes, seconds),
            "depacketize": measure(aiortc_depay, nbytes, seconds),
        }
        result["aiortc"] = theirs
        ours = result["ours"]
        assert isinstance(ours, dict)
        result["ratio_vs_aiortc"] = {
            k: ours[k]["MB_per_s"] / theirs[k]["MB_per_s"] for k in ("packetize", "depacketize")
        }
    return result


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--seconds", type=float, default=1.0, help="time per measurement")
    ap.add_argument("--out", type=Path, default=RESULTS)
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    mtu = aiortc_h264.PACKET_MAX  # same packet size as the baseline
    report: dict[str, object] = {
        "width": WIDTH, "height": HEIGHT, "bitrate_bps": BITRATE_BPS, "mtu": mtu,
        "python": sys.version.split()[0], "av": av.__version__,
        "machine": platform.machine(), "processor": platform.processor(),
    }
    for codec in ("h264", "hevc"):
        t0 = time.perf_counter()
        aus = encode_frames(codec, args.frames)
        logger.info("%s: encoded %d frames, %.1f kB in %.1f s", codec, len(aus),
                    sum(map(len, aus)) / 1e3, time.perf_counter() - t0)
        res = bench_codec(codec, aus, mtu, args.seconds)
        report[codec] = res
        ours = res["ours"]
        assert isinstance(ours, dict)
        for k, v in ours.items():
            logger.info("%s ours   %-26s %8.1f MB/s %10.0f packets/s", codec, k, v["MB_per_s"], v["packets_per_s"])
        if "aiortc" in res:
            theirs = res["aiortc"]
            assert isinstance(theirs, dict)
            for k, v in theirs.items():
                logger.info("%s aiortc %-26s %8.1f MB/s %10.0f packets/s", codec, k, v["MB_per_s"], v["packets_per_s"])
            ratio = res["ratio_vs_aiortc"]
            assert isinstance(ratio, dict)
            for k, r in ratio.items():
                logger.info("%s ratio ours/aiortc %-12s %.2fx", codec, k, r)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=2) + "\n")
    logger.info("wrote %s", args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
