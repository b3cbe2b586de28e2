"""End-to-end motion-to-photon latency of live sessions, broken down per stage.

The relay and the client run in this process on loopback (asyncio; the client has its
own GL thread and codec thread); the server's event loop runs here too, its rendering
and encoding in a render worker process (``splitrender.server.worker``).  With the
worker (against the JSON of the last run before it, an earlier session, same machine):
motion-to-photon of ``video`` at ``ideal`` 37.3 to 27.1 ms mean (p95 53 to 28 ms),
``atw`` 61.9 to 36.3 ms (p95 124 to 51 ms); server render + encode of ``atw`` 22.0 to
15.8 ms; 104-113 to 115-117 updates in 4 s.  The server's GL work no longer holds the
interpreter lock the relay and client need.  For ``video`` and
``atw`` under the ``ideal`` and ``lan`` profiles (through the relay in both cases),
each displayed frame's stages are measured on the wall clock:

* pose uplink: client samples the pose → the server starts the frame that uses it;
* server render, encode (the session's render worker);
* packetize + network: encode done → last RTP packet of the frame received;
* decode: received → decoded (includes waiting in the decode queue);
* wait for display: decoded → the display tick that first shows it;
* client render: apply + render on the client's GL thread.

Motion-to-photon = displayed − pose sampled.  Writes ``benchmarks/results/bench_e2e.json``.

    python benchmarks/bench_e2e.py [--duration 4] [--scene minimal] [--size 320x180]
"""

from __future__ import annotations

import argparse
import asyncio
import json
import logging
import platform
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from splitrender.client.session import ClientConfig, LiveClient
from splitrender.netsim import Relay, parse_path
from splitrender.server.server import LiveServer, ServerConfig

LOOPBACK = "127.0.0.1"
RESULTS = Path(__file__).parent / "results" / "bench_e2e.json"
STAGES = ("pose_uplink_age_ms", "server_render_ms", "server_encode_ms", "network_ms", "decode_ms",
          "wait_display_ms", "client_ms")


async def one_run(method: str, network: str, duration_s: float, scene: str, width: int, height: int) -> dict[str, Any]:
    cfg = ServerConfig(host=LOOPBACK, port=0, udp_port=0, scene=scene, server_fps=30)
    async with LiveServer(cfg) as server:
        serve = asyncio.create_task(server.serve_forever())
        relay = Relay(parse_path(network), seed=1)
        try:
            tcp = await relay.start_tcp((LOOPBACK, 0), server.tcp_address)
            udp = await relay.start_udp((LOOPBACK, 0), server.udp_address)
            with tempfile.TemporaryDirectory() as tmp:
                result = await LiveClient(ClientConfig(port=tcp[1], udp_port=udp[1], methods=(method,), width=width,
                                                       height=height, duration_s=duration_s, trace="walk",
                                                       out_dir=Path(tmp))).run()
        finally:
            await relay.wait_tcp_idle(1.0)  # let the relay see both TCP sides close before closing it
            await relay.close()
            serve.cancel()
            await asyncio.gather(serve, return_exceptions=True)
    # one sample per update (its first display), so repeated displays do not weigh in
    first = {}
    for r in result.rows:
        first.setdefault(r["update_frame_id"], r)
    rows = list(first.values())[3:]  # skip the start-up frames

    def stat(key: str) -> dict[str, float]:
        a = np.array([r[key] for r in rows], dtype=np.float64)
        return {"mean": float(a.mean()), "p50": float(np.median(a)), "p95": float(np.percentile(a, 95))}

    out: dict[str, Any] = {"method": method, "network": network, "updates": len(rows),
                           "displayed_frames": len(result.rows), "stages_ms": {k: stat(k) for k in STAGES},
                           "motion_to_photon_ms": stat("motion_to_photon_ms"), "update_age_ms": stat("update_age_ms"),
                           "counters": result.counters}
    stage_sum = sum(out["stages_ms"][k]["mean"] for k in STAGES)
    out["stage_sum_ms"] = stage_sum
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=4.0)
    ap.add_argument("--scene", default="minimal")
    ap.add_argument("--size", default="320x180")
    ap.add_argument("--out", type=Path, default=RESULTS)
    ns = ap.parse_args()
    logging.basicConfig(level=logging.WARNING)
    w, h = (int(v) for v in ns.size.split("x"))
    runs = []
    t0 = time.perf_counter()
    for method in ("video", "atw"):
        for network in ("ideal", "lan"):
            r = asyncio.run(one_run(method, network, ns.duration, ns.scene, w, h))
            runs.append(r)
            st = r["stages_ms"]
            print(f"{method:5s} {network:5s} m2p {r['motion_to_photon_ms']['mean']:6.1f} ms = "
                  + " + ".join(f"{k.replace('_ms', '')} {st[k]['mean']:.1f}" for k in STAGES))
    base = {r["method"]: r for r in runs if r["network"] == "ideal"}
    for r in runs:
        r["m2p_ratio_vs_ideal"] = r["motion_to_photon_ms"]["mean"] / base[r["method"]]["motion_to_photon_ms"]["mean"]
    doc = {"benchmark": "bench_e2e", "scene": ns.scene, "size": ns.size, "duration_s": ns.duration,
           "server_fps": 30, "display_hz": 60, "tracker_hz": 120, "machine": platform.machine(),
           "python": platform.python_version(), "wall_s": time.perf_counter() - t0, "runs": runs}
    ns.out.parent.mkdir(parents=True, exist_ok=True)
    ns.out.write_text(json.dumps(doc, indent=2))
    print(f"-> {ns.out}")


if __name__ == "__main__":
    main()
