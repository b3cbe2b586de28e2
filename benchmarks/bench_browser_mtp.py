"""Motion-to-photon in the browser beside the headless client: the same server, scene, trace and path.

For each path (loopback, and a relay adding ``--delay`` each way) and each method the page draws (video, atw, sas),
one 5 s session of the page in headless Chromium (:mod:`splitrender.webrtc.driver`) and one of the headless
client (``splitrender client`` in its own process; through ``splitrender shape`` where the path is shaped), on
the ``minimal`` scene at 320x180, the ``turn`` trace, both clients displaying at 60 Hz and both given H.264 4:2:0
(the server's ``--param METHOD.chroma=420``, so both decode the same kind of stream).  Motion-to-photon is each
client's own ``motion_to_photon_ms``: a displayed frame's display time less the time of the client pose the server
rendered it from (the same definition in both, on the same clock).  The JSON keeps per run the mean, median and
95th percentile of MTP and update age, and per (path, method) the browser/headless ratio of mean MTP; the PNG
draws them side by side.

    python benchmarks/bench_browser_mtp.py [--seconds 5] [--delay 25] [--out FILE]
"""

from __future__ import annotations

import argparse
import json
import platform
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from splitrender.client.score import read_frames
from splitrender.webrtc.driver import PageDriver, ServerProcess, browser_missing

RESULTS = Path(__file__).parent / "results" / "bench_browser_mtp.json"
METHODS = ("video", "atw", "sas")


def _port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _stats(rows: list[dict], key: str) -> dict[str, float]:
    a = np.array([r.get(key, np.nan) for r in rows], float)
    a = a[np.isfinite(a)]
    if not a.size:
        return {f"{key}_mean": float("nan"), f"{key}_p50": float("nan"), f"{key}_p95": float("nan")}
    return {f"{key}_mean": float(a.mean()), f"{key}_p50": float(np.percentile(a, 50)),
            f"{key}_p95": float(np.percentile(a, 95))}


def _ports_of(server: ServerProcess) -> tuple[int, int]:
    for line in server.log:
        if "serving on tcp" in line:
            tcp = line.split("tcp ")[1].split(",")[0].rsplit(":", 1)[1]
            udp = line.split("udp ")[1].strip().rsplit(":", 1)[1]
            return int(tcp), int(udp)
    raise RuntimeError("no ports in the server's log")


def headless(tcp: int, udp: int, method: str, seconds: float, out: Path, netem: str | None) -> list[dict]:
    relay = None
    port, udp_port = tcp, udp
    if netem:
        port, udp_port = _port(), _port()
        relay = subprocess.Popen([sys.executable, "-m", "splitrender.cli", "shape", "--listen-tcp", f"127.0.0.1:{port}",
                                  "--to-tcp", f"127.0.0.1:{tcp}", "--udp", f"127.0.0.1:{udp_port}=127.0.0.1:{udp}",
                                  "--netem", netem], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        time.sleep(1.5)
    try:
        subprocess.run([sys.executable, "-m", "splitrender.cli", "client", "--port", str(port), "--udp-port",
                        str(udp_port), "--method", method, "--trace", "turn", "--duration", str(seconds), "--width", "320",
                        "--height", "180", "--display-hz", "60", "--out", str(out)], check=True,
                       stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, timeout=seconds + 120)
    finally:
        if relay is not None:
            relay.terminate()
            relay.wait(10)
    return read_frames(out / "frames.csv")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=5.0)
    ap.add_argument("--delay", type=float, default=25.0, help="one-way delay of the shaped path, ms")
    ap.add_argument("--out", type=Path, default=RESULTS)
    a = ap.parse_args()
    why = browser_missing()
    if why:
        sys.exit(f"bench_browser_mtp: {why}")
    paths = {"loopback": None, f"delay {a.delay:g}ms": f"delay {a.delay:g}ms"}
    runs, ratios = [], {}
    tmp = Path(tempfile.mkdtemp(prefix="sr-mtp-"))
    t0 = time.perf_counter()
    with PageDriver() as driver:
        for label, netem in paths.items():
            args = ["--scene", "minimal", "--methods", ",".join(METHODS), "--out", str(tmp / "srv")]
            args += [f"--param={m}.chroma=420" for m in METHODS]
            if netem:
                args += ["--webrtc-network", netem]
            with ServerProcess(args) as server:
                tcp, udp = _ports_of(server)
                for method in METHODS:
                    pair = {}
                    res = driver.session(server.url, method, trace="turn", duration_s=a.seconds, record_every=0)
                    if not res.get("ok"):
                        sys.exit(f"browser session failed: {res}")
                    rows = read_frames(tmp / "srv" / res["session_id"] / "frames.csv")
                    pair["browser"] = rows
                    pair["headless"] = headless(tcp, udp, method, a.seconds, tmp / f"hl_{label}_{method}".replace(" ", "_"), netem)
                    for client, rows in pair.items():
                        r = {"path": label, "method": method, "client": client, "rows": len(rows),
                             **_stats(rows, "motion_to_photon_ms"), **_stats(rows, "update_age_ms")}
                        runs.append(r)
                        print(f"{label:14s} {method:6s} {client:9s} MTP {r['motion_to_photon_ms_mean']:6.1f} ms "
                              f"(p50 {r['motion_to_photon_ms_p50']:6.1f}, p95 {r['motion_to_photon_ms_p95']:6.1f}), "
                              f"update age {r['update_age_ms_mean']:6.1f} ms, {len(rows)} rows", flush=True)
                    b, h = (next(x for x in runs[-2:] if x["client"] == c)["motion_to_photon_ms_mean"]
                            for c in ("browser", "headless"))
                    ratios[f"{label}/{method}"] = b / h if h else float("nan")
    out = {"benchmark": "bench_browser_mtp", "scene": "minimal", "size": "320x180", "trace": "turn",
           "seconds": a.seconds, "paths": list(paths), "runs": runs,
           "ratio_browser_over_headless_mtp": ratios, "wall_s": time.perf_counter() - t0,
           "machine": {"python": platform.python_version(), "processor": platform.processor() or platform.machine()}}
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps(out, indent=2))
    _chart(runs, a.out.with_suffix(".png"))
    print(f"wrote {a.out}: browser/headless MTP " + ", ".join(f"{k} {v:.2f}x" for k, v in ratios.items()))


def _chart(runs: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    groups = sorted({(r["path"], r["method"]) for r in runs}, key=lambda g: (list(dict.fromkeys(r["path"] for r in runs)).index(g[0]), g[1]))
    fig, ax = plt.subplots(figsize=(7, 3.6))
    x = np.arange(len(groups))
    for i, (client, colour) in enumerate((("headless", "#4878a8"), ("browser", "#e07b39"))):
        sel = [next(r for r in runs if (r["path"], r["method"], r["client"]) == (*g, client)) for g in groups]
        mean = [r["motion_to_photon_ms_mean"] for r in sel]
        lo = [r["motion_to_photon_ms_mean"] - r["motion_to_photon_ms_p50"] for r in sel]
        hi = [r["motion_to_photon_ms_p95"] - r["motion_to_photon_ms_mean"] for r in sel]
        ax.bar(x + (i - 0.5) * 0.38, mean, 0.38, color=colour, label=f"{client} client",
               yerr=[np.maximum(lo, 0), np.maximum(hi, 0)], capsize=3)
    ax.set_xticks(x, [f"{m}\n{p}" for p, m in groups])
    ax.set_ylabel("motion-to-photon, ms (mean; bars to p50 and p95)")
    ax.set_title("pose sent to pixels shown: browser (WebRTC) beside headless (RTP/TCP)")
    ax.legend(frameon=False)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


if __name__ == "__main__":
    main()
