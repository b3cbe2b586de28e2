"""Live loss recovery: how many server frames reach the screen, and the longest freeze, under loss.

A live ``video`` session (server, shaping relay and client in one process on loopback)
under three downlink+uplink profiles, the lossless one first as the baseline measured
in the same run:

* ``delay 20ms``: no loss;
* ``delay 20ms loss 2%``: independent loss (issue 14's target: at least 90% of the
  server's frames shown, no freeze over 250 ms; judged on the FEC run);
* ``delay 20ms loss gemodel 4% 30% 70% 0.5%``: bursty Gilbert-Elliott loss (about 7%
  of packets; target: recovery within one GOP, most frames shown).

The server runs in its own process, the relay and the client in this one.  Per run:
the server frames between the first and the last one shown, distinct updates shown and their share, the share
relative to the lossless run, the longest time between two new updates on screen
(the freeze), the update age's 95th percentile, and the client's NACK, PLI and stall
counters.  Writes ``benchmarks/results/bench_loss_recovery.json``.

Each profile runs with NACK alone and with FEC (``serve --fec``: an RFC 5109 parity packet per
group of up to 16 RTP packets).  Measured in two runs (6 s, 320x180, seed 1; the shares move with the
machine's load): lossless 82-94% shown with NACK alone and 99-100% with FEC, longest freeze 34-71 ms;
2% loss 49-53% shown with NACK alone (longest freeze 300-333 ms) and 90.5-91.1% with FEC (233-234
ms; 22-23 packets rebuilt), which meets the target at its edge, for 11% more downlink packets; bursty
loss 13-22% against 27-31%, freezes 0.80-1.20 s against 0.74-0.93 s.  Without FEC each loss holds the
next two or three frames until the retransmission lands (H.264 decodes in order); they then reach the
display within one tick, where only the newest is shown.  FEC rebuilds a single loss per group
without a round trip; bursts that take two packets of a group still wait for NACK or a keyframe.

Then three runs with a patient client (:data:`PATIENT_KW` and ``--playout``, default 300 ms: an update is
shown no earlier than its server time + 300 ms, so frames held behind a retransmission are shown in turn; six
NACK tries; a frame given up after 600 ms; a stall PLI after 15 frame intervals): 2% loss with FEC, and the
bursty profile with NACK alone and with FEC.  Two runs after the render workers landed (6 s, seed 1):

| profile | NACK | FEC | patient, NACK | patient, FEC |
|---|---|---|---|---|
| lossless | 100 / 87% | 86 / 94% | | |
| 2% loss | 43 / 56% | 88 / 68% | | 95 / 99% shown, longest freeze 68 / 69 ms |
| bursty | 20 / 21% | 31 / 28% | 47 / 55% (freeze 600 / 435 ms) | 60 / 61% (freeze 366 / 400 ms) |

The immediate-display runs are noisy: at ``display_hz`` = ``server_fps`` = 30 a frame that arrives a little
late lands in the same tick as the next one and is never seen, which the playout delay also absorbs.  The
issue's targets (2%: at least 90% shown and no freeze over 250 ms; bursty: recovery within one GOP and most
frames shown) are met by the patient client with FEC, at 300 ms more motion-to-photon latency (95th
percentile update age 313 ms at 2% loss, 630-693 ms under bursts).  Without the delay the bursty profile shows
20-31%.  With the bursts on the downlink only the immediate client shows 36-41% (NACK): uplink bursts take the
NACKs and PLIs, sparse RTCP datagrams, so an uplink bad state lasts long in time.

    python benchmarks/bench_loss_recovery.py [--duration 8] [--size 320x180] [--seed 1] [--playout 300]
"""

from __future__ import annotations

import argparse
import asyncio
import json
import logging
import platform
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's package, not an installed one

from splitrender.client.session import ClientConfig, LiveClient  # noqa: E402
from splitrender.netsim import Relay, parse_path  # noqa: E402

from _live import LOOPBACK, served  # noqa: E402  (beside this script)

RESULTS = Path(__file__).parent / "results" / "bench_loss_recovery.json"
PROFILES = ("delay 20ms", "delay 20ms loss 2%", "delay 20ms loss gemodel 4% 30% 70% 0.5%")
GOP_S = 1.0
CLIENT_KW: dict[str, Any] = {}
PATIENT_KW: dict[str, Any] = {"nack_max_tries": 6, "jitter_timeout_ms": 600.0, "stall_frames": 15.0}
"""The patient client of the playout runs: more NACK tries, a frame given up after 600 ms (not 300), a stall (and
its PLI) after 15 frame intervals (not 6), so a burst is repaired by retransmission instead of a keyframe."""
TARGET_SHOWN = 0.9
TARGET_FREEZE_MS = 250.0


async def one_run(network: str, duration_s: float, width: int, height: int, seed: int, fec: bool = False,
                  playout_ms: float = 0.0) -> dict[str, Any]:
    """One session; with ``playout_ms`` > 0 the client is also :data:`PATIENT_KW`.  The server runs in its own
    process (:func:`_live.served`)."""
    async with served(["--scene", "minimal", "--methods", "video", *(["--fec"] if fec else [])]) as (port, udp_port):
        relay = Relay(parse_path(network), seed=seed)
        try:
            tcp = await relay.start_tcp((LOOPBACK, 0), (LOOPBACK, port))
            udp = await relay.start_udp((LOOPBACK, 0), (LOOPBACK, udp_port))
            with tempfile.TemporaryDirectory() as tmp:
                result = await LiveClient(ClientConfig(port=tcp[1], udp_port=udp[1], width=width, height=height,
                                                       display_hz=30, duration_s=duration_s, trace="walk",
                                                       **{**CLIENT_KW, **(PATIENT_KW if playout_ms > 0 else {})},
                                                       playout_delay_ms=playout_ms, out_dir=Path(tmp))).run()
        finally:
            await relay.wait_tcp_idle(1.0)  # let the relay see both TCP sides close before closing it
            stats = relay.stats()
            await relay.close()
    rows = [r for r in result.rows if r["update_frame_id"] != -1]
    ids = [int(r["update_frame_id"]) for r in rows]
    new_at = [r["displayed_us"] / 1e6 for k, r in enumerate(rows) if k == 0 or ids[k] != ids[k - 1]]
    gaps = np.diff(new_at) if len(new_at) > 1 else np.array([np.nan])
    ages = np.array([r["update_age_ms"] for r in rows], dtype=np.float64)
    span = (max(ids) - min(ids) + 1) if ids else 0  # server frames between the first and last shown
    shown = len(set(ids))
    c = result.counters
    return {
        "network": network, "fec": fec, "playout_delay_ms": playout_ms, "frames_in_span": span, "updates_shown": shown,
        "shown_share": shown / span if span else float("nan"),
        "longest_freeze_ms": float(np.nanmax(gaps) * 1000), "p95_update_age_ms": float(np.percentile(ages, 95)) if len(ages) else float("nan"),
        "downlink_packets_dropped": stats.downlink.packets_dropped, "downlink_packets": stats.downlink.packets_in,
        "nacks_sent": c.get("nacks_sent", 0), "nacked_packets": c.get("nacked_packets", 0), "plis_sent": c.get("plis_sent", 0),
        "stalls": c.get("stalls", 0), "keyframes_received": c.get("keyframes_received", 0),
        "fec_packets": c.get("color_fec_packets", 0), "fec_recovered": c.get("color_fec_recovered", 0),
        "downlink_kbps": float(stats.downlink.bytes_in * 8 / duration_s / 1000),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=8.0)
    ap.add_argument("--size", default="320x180")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--playout", type=float, default=300.0,
                    help="playout delay (ms) of the patient-client runs (2%% loss with FEC, bursty with NACK and FEC)")
    ap.add_argument("--out", type=Path, default=RESULTS)
    ns = ap.parse_args()
    logging.basicConfig(level=logging.ERROR)
    w, h = (int(v) for v in ns.size.split("x"))
    t0 = time.perf_counter()
    runs = []
    plans = [(n, f, 0.0) for n in PROFILES for f in (False, True)]
    plans += [(PROFILES[1], True, ns.playout)] + [(PROFILES[2], f, ns.playout) for f in (False, True)]  # patient client
    for net, fec, playout in plans:
        r = asyncio.run(one_run(net, ns.duration, w, h, ns.seed, fec, playout))
        runs.append(r)
        print(f"{net:42s} {'FEC' if fec else 'NACK':4s} playout {playout:3.0f} ms shown {r['updates_shown']}/{r['frames_in_span']} ({r['shown_share']:.1%}), "
              f"longest freeze {r['longest_freeze_ms']:.0f} ms, p95 age {r['p95_update_age_ms']:.0f} ms, "
              f"dropped {r['downlink_packets_dropped']}/{r['downlink_packets']} packets, NACKs {r['nacks_sent']}, "
              f"PLIs {r['plis_sent']}, FEC rebuilt {r['fec_recovered']}", flush=True)
    for r in runs:
        base = next(b for b in runs if b["network"] == PROFILES[0] and b["fec"] == r["fec"])
        r["shown_ratio_vs_lossless"] = r["shown_share"] / base["shown_share"]
    nack2, two, nack_burst, burst, two_po, nack_burst_po, burst_po = runs[2:9]
    doc = {
        "benchmark": "bench_loss_recovery", "method": "video", "scene": "minimal", "size": ns.size,
        "duration_s": ns.duration, "server_fps": 30, "display_hz": 30, "seed": ns.seed, "runs": runs,
        "targets": {
            "loss_2pct_shown_at_least": TARGET_SHOWN, "loss_2pct_freeze_under_ms": TARGET_FREEZE_MS,
            "loss_2pct_met": bool(two["shown_share"] >= TARGET_SHOWN and two["longest_freeze_ms"] < TARGET_FREEZE_MS),
            "bursty_recovers_within_gop": bool(burst["longest_freeze_ms"] < GOP_S * 1000),
            "patient_playout_delay_ms": ns.playout, "patient_client": PATIENT_KW,
            "loss_2pct_patient_met": bool(two_po["shown_share"] >= TARGET_SHOWN and two_po["longest_freeze_ms"] < TARGET_FREEZE_MS),
            "bursty_with_playout_most_shown": bool(burst_po["shown_share"] > 0.5),
            "bursty_with_playout_recovers_within_gop": bool(burst_po["longest_freeze_ms"] < GOP_S * 1000),
            "bursty_shown_playout_over_none_fec": burst_po["shown_share"] / burst["shown_share"],
            "bursty_shown_playout_over_none_nack": nack_burst_po["shown_share"] / nack_burst["shown_share"],
            "loss_2pct_shown_fec_over_nack": two["shown_share"] / nack2["shown_share"],
            "bursty_shown_fec_over_nack": burst["shown_share"] / nack_burst["shown_share"],
        },
        "machine": platform.machine(), "python": platform.python_version(), "wall_s": time.perf_counter() - t0,
    }
    ns.out.parent.mkdir(parents=True, exist_ok=True)
    ns.out.write_text(json.dumps(doc, indent=2))
    print(json.dumps(doc["targets"], indent=2))
    print(f"-> {ns.out}")


if __name__ == "__main__":
    main()
