"""How fast the live system runs: server updates per second, client display rate, and where a frame's time goes.

One measurement is a real live session: a :class:`~splitrender.server.server.LiveServer`
in this process (its render worker a process of its own, as ``splitrender serve``
runs it) and ``splitrender client`` as a separate process, on loopback, for one method.
The server's ``updates.csv`` gives each frame's stages (milliseconds):

- ``gi``: relighting the scene's DDGI probes (inside the render of whichever method asked first);
- ``method``: the method's work less that (shared producer work and the session's own render and packing);
- ``encode``: the video encoders;
- ``worker_rtt``: the round trip to the render worker beyond its own time (pickling, the pipe, this loop);
- ``send``: packetizing, the control messages and the datagrams.

``worker_cpu_ms_per_update`` is the render worker's CPU time over the session (every thread, llvmpipe's
included; the session's set-up too) per update made: on a machine shared with other work it moves far less than
the rates and the wall-clock stages do.

Whatever is left of each frame interval is ``wait``: the frame clock waiting for its next
tick (a server that keeps up at ``server_fps`` waits) or the event loop busy elsewhere.
The client's ``frames.csv`` and ``counters.json`` give its display rate (display ticks
shown against those skipped for being more than a tick late) and its per-tick
milliseconds (apply + render).

``benchmarks/bench_live_rate.py`` runs every method with the probes relit every frame
(the baseline, as the ground truth does) and at the live server's own rate;
the ``live`` study charts the same figures in the report.
"""

from __future__ import annotations

import asyncio
import csv
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from splitrender.server.server import LiveServer, ServerConfig

LOOPBACK = "127.0.0.1"
STAGES = ("gi", "method", "encode", "worker_rtt", "send")
WARMUP_S = 1.0
"""Frames in the session's first second are left out (encoder start, the first relight, the client's set-up)."""


def _read_csv(path: Path) -> list[dict[str, str]]:
    if not path.is_file():
        return []
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def _f(row: dict[str, str], key: str) -> float:
    try:
        return float(row.get(key, "nan") or "nan")
    except ValueError:
        return math.nan


def summarise_server(rows: list[dict[str, str]]) -> dict[str, float]:
    """Updates per second and mean stage milliseconds of one session's ``updates.csv`` rows, past the warm-up."""
    if not rows:
        return {"updates": 0, "updates_per_s": 0.0, **{f"{s}_ms": math.nan for s in STAGES}}
    t = np.array([_f(r, "server_us") for r in rows]) / 1e6
    keep = t >= t[0] + WARMUP_S
    kept = [r for r, k in zip(rows, keep) if k]
    tk = t[keep]
    ups = (len(tk) - 1) / (tk[-1] - tk[0]) if len(tk) >= 3 and tk[-1] > tk[0] else math.nan

    def mean(key: str) -> float:
        v = np.array([_f(r, key) for r in kept])
        v = v[np.isfinite(v)]
        return float(v.mean()) if v.size else math.nan

    gi = mean("gi_ms")
    gi = 0.0 if math.isnan(gi) else gi
    out = {"updates": len(rows), "updates_per_s": float(ups), "gi_ms": gi,
           "method_ms": mean("shared_ms") + mean("server_ms") - gi, "encode_ms": mean("encode_ms"),
           "worker_rtt_ms": mean("worker_rtt_ms"), "send_ms": mean("send_ms"),
           "keyframes": int(sum(int(_f(r, "keyframe") or 0) for r in rows)),
           "kbps": float(sum(_f(r, "bytes") for r in kept) * 8 / 1000 / (tk[-1] - tk[0])) if len(tk) >= 3 and tk[-1] > tk[0] else math.nan}
    interval = 1000.0 / ups if ups and math.isfinite(ups) else math.nan
    out["frame_ms"] = interval
    out["wait_ms"] = max(0.0, interval - sum(out[f"{s}_ms"] for s in STAGES)) if math.isfinite(interval) else math.nan
    return out


def summarise_client(out: Path, display_hz: float, duration_s: float) -> dict[str, float]:
    """Display rate (ticks shown per second of the run) and mean per-tick milliseconds of one client recording."""
    rows = _read_csv(out / "frames.csv")
    counters: dict[str, Any] = {}
    if (out / "counters.json").is_file():
        counters = json.loads((out / "counters.json").read_text())
    shown = [r for r in rows if _f(r, "update_frame_id") >= 0]
    client_ms = np.array([_f(r, "client_ms") for r in shown])
    client_ms = client_ms[np.isfinite(client_ms)]
    decode_ms = np.array([_f(r, "decode_ms") for r in shown])
    decode_ms = decode_ms[np.isfinite(decode_ms)]
    span = duration_s
    if shown:
        t = np.array([_f(r, "displayed_us") for r in shown]) / 1e6
        span = max(float(t[-1] - t[0]), 1e-3)
    return {"display_hz": display_hz, "ticks": len(rows), "shown": len(shown),
            "displayed_per_s": (len(shown) - 1) / span if len(shown) > 1 else 0.0,
            "late_ticks": int(counters.get("late_ticks", 0)),
            "client_ms": float(client_ms.mean()) if client_ms.size else math.nan,
            "decode_ms": float(decode_ms.mean()) if decode_ms.size else math.nan}


def _cpu_s(pid: int | None) -> float:
    """User + system CPU seconds of process ``pid`` (all its threads: llvmpipe's rasterisers too); NaN if gone."""
    try:
        f = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        return (int(f[11]) + int(f[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError):
        return math.nan


def _workers_cpu(srv: LiveServer) -> dict[int, float]:
    return {w.pid: _cpu_s(w.pid) for w in list(srv.workers) if w.pid is not None}


async def _session(method: str, seconds: float, scene: str, width: int, height: int, display_hz: float,
                   server_fps: int, gi_hz: float, out: Path, params: dict[str, Any] | None,
                   cpu: dict[str, float]) -> tuple[int, str]:
    cfg = ServerConfig(host=LOOPBACK, port=0, udp_port=0, scene=scene, server_fps=server_fps, methods=(method,),
                       method_params={method: dict(params)} if params else {}, out_dir=out / "server", gi_hz=gi_hz,
                       metrics_interval_s=0)
    async with LiveServer(cfg) as srv:
        serve = asyncio.create_task(srv.serve_forever())
        cpu0 = _workers_cpu(srv)
        last = dict(cpu0)

        async def poll() -> None:       # a worker's last reading before its session closes it
            while True:
                last.update({p: c for p, c in _workers_cpu(srv).items() if math.isfinite(c)})
                await asyncio.sleep(0.25)

        poller = asyncio.create_task(poll())
        try:
            cmd = [sys.executable, "-c", "from splitrender.cli import main; main()", "client",
                   "--port", str(srv.tcp_address[1]), "--method", method, "--width", str(width), "--height", str(height),
                   "--display-hz", f"{display_hz:g}", "--duration", f"{seconds:g}", "--out", str(out / "client"),
                   "--metrics-interval", "0", "--stall-timeout", "30", "--connect-timeout", "60"]
            proc = await asyncio.create_subprocess_exec(*cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                                                        env={**os.environ, "PYTHONUNBUFFERED": "1"})
            try:
                _, err = await asyncio.wait_for(proc.communicate(), seconds + 120)
            except TimeoutError:
                proc.kill()
                _, err = await proc.communicate()
            # the session's worker is the busiest (the spare that starts behind it only loads the scene)
            last.update({p: c for p, c in _workers_cpu(srv).items() if math.isfinite(c)})
            cpu["worker_cpu_s"] = max((c - cpu0.get(pid, 0.0) for pid, c in last.items()), default=math.nan)
            return int(proc.returncode or 0), err.decode(errors="replace")[-2000:]
        finally:
            poller.cancel()
            serve.cancel()
            await asyncio.gather(serve, return_exceptions=True)


def measure(method: str, *, seconds: float = 8.0, scene: str = "default", width: int = 320, height: int = 180,
            display_hz: float = 30.0, server_fps: int = 30, gi_hz: float = 0.0, out: Path | None = None,
            params: dict[str, Any] | None = None) -> dict[str, Any]:
    """One live session of ``method``; the server's and the client's figures (see the module docstring)."""
    tmp = None
    if out is None:
        tmp = tempfile.TemporaryDirectory(prefix="sr-live-rate-")
        out = Path(tmp.name)
    try:
        w0 = time.perf_counter()
        cpu: dict[str, float] = {}
        rc, err = asyncio.run(_session(method, seconds, scene, width, height, display_hz, server_fps, gi_hz, out, params,
                                       cpu))
        wall = time.perf_counter() - w0
        sessions = sorted((out / "server").glob("*/updates.csv"))
        srv = summarise_server(_read_csv(sessions[0]) if sessions else [])
        cli = summarise_client(out / "client", display_hz, seconds)
        row: dict[str, Any] = {"method": method, "scene": scene, "size": f"{width}x{height}", "gi_hz": gi_hz,
                               "server_fps": server_fps, "seconds": seconds, "client_rc": rc, "wall_s": wall,
                               "worker_cpu_s": cpu.get("worker_cpu_s", math.nan),
                               "worker_cpu_ms_per_update": cpu.get("worker_cpu_s", math.nan) * 1e3 / srv["updates"]
                               if srv["updates"] else math.nan,
                               **srv, **{f"client_{k}" if not k.startswith("client") else k: v for k, v in cli.items()}}
        if rc != 0:
            row["client_error"] = err.strip().splitlines()[-1] if err.strip() else f"exit {rc}"
        return row
    finally:
        if tmp is not None:
            tmp.cleanup()
