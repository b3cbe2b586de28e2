"""Virtual time against live: the same seeded session run both ways through the same impairment.

Both modes run the same session cores (:mod:`splitrender.pipeline.session`), so under
loss they should show the same share of frames, freeze as long, and send as many
NACKs, PLIs and keyframes.  :func:`run_cell` runs one cell of the grid both ways:

* **virtual time**: :class:`~splitrender.sim.runner.VirtualTimeRun` with the network
  model on the simulated clock;
* **live**: a :class:`~splitrender.server.server.LiveServer` (its render worker in
  another process), the shaping :class:`~splitrender.netsim.Relay` on loopback with the
  same impairment string, and a :class:`~splitrender.client.session.LiveClient`, all on
  one event loop; the recording is scored afterwards like a virtual-time run.

The set-up (:data:`SETUP`) is one the live server keeps up with on two cores: ``video``
on the ``minimal`` scene at 160x90, 15 server frames and 30 display ticks a second, so
what differs between the modes is the protocol and the network, not a server that
skips ticks.  ``mtu_bytes`` 300 spreads each frame over several packets so that 2 %
loss hits enough packets in a short run to compare counts.

Both modes summarise with :func:`~splitrender.pipeline.session_summary` (the same
definitions of frames shown, longest freeze, NACKs, PLIs, keyframes).
"""

from __future__ import annotations

import asyncio
import logging
import math
import tempfile
import time
from pathlib import Path
from typing import Any

from ..client.score import score_recording
from ..client.session import ClientConfig, LiveClient
from ..netsim import Relay, parse_path
from ..pipeline import session_summary
from ..server.server import LiveServer, ServerConfig
from ..sim.config import RunConfig
from ..sim.runner import VirtualTimeRun

log = logging.getLogger(__name__)

SETUP: dict[str, Any] = {"method": "video", "scene": "minimal", "trace": "walk", "width": 160, "height": 90,
                         "server_fps": 15, "client_fps": 30, "mtu_bytes": 300}
"""The session both modes run (see the module docstring for why)."""

IMPAIRMENTS: dict[str, str] = {
    "none": "delay 20ms",
    "loss 2%": "delay 20ms loss 2%",
    "bursty": "delay 20ms loss gemodel 4% 30% 70% 0.5%",
    "rate": "delay 20ms rate 200kbit",
}
"""Each direction's impairment (netem syntax); ``rate`` is below the stream's 360 kbit/s (measured), so its queue and
the update age grow through the run (the queue of 1000 packets does not overflow in 8 s)."""

RECOVERY: dict[str, dict[str, Any]] = {
    "nack": {},
    "nack+fec": {"fec": True},
    "patient": {"fec": True, "playout_delay_ms": 300.0, "nack_max_tries": 6, "jitter_timeout_ms": 600.0, "stall_frames": 15.0},
    "no nack": {"nack_max_tries": 0},
}
"""Loss-recovery set-ups: NACK alone (the default), with FEC, the README's patient client, neither."""

COMPARED = ("rtp_packets", "shown_pct", "longest_freeze_ms", "nacks", "keyframe_requests", "keyframes", "mean_psnr_db",
            "packets_lost", "retransmitted", "fec_recovered", "mean_update_age_ms")


def _run_config(network: str, recovery: dict[str, Any], duration_s: float, seed: int) -> Any:
    kw = {k: v for k, v in recovery.items() if k != "fec"}
    return RunConfig.from_dict({**SETUP, "network": network, "duration_s": duration_s, "seed": seed, "flip_every": 0,
                                "jitter_timeout_ms": kw.pop("jitter_timeout_ms", 300.0), "fec": bool(recovery.get("fec")),
                                **kw})


def run_virtual(network: str, recovery: dict[str, Any], duration_s: float, seed: int, renderer: Any = None) -> dict[str, Any]:
    """One virtual-time run of the cell; its summary."""
    cfg = _run_config(network, recovery, duration_s, seed)
    res = VirtualTimeRun(cfg, renderer=renderer).run()
    return dict(res.summary)


async def _live(network: str, recovery: dict[str, Any], duration_s: float, seed: int, out: Path) -> dict[str, Any]:
    host = "127.0.0.1"
    scfg = ServerConfig(host=host, port=0, udp_port=0, scene=SETUP["scene"], server_fps=SETUP["server_fps"],
                        methods=(SETUP["method"],), mtu_bytes=SETUP["mtu_bytes"], fec=bool(recovery.get("fec")),
                        metrics_interval_s=0)
    async with LiveServer(scfg) as server:
        serve = asyncio.create_task(server.serve_forever())
        relay = Relay(parse_path(network), seed=seed)
        try:
            tcp = await relay.start_tcp((host, 0), server.tcp_address)
            udp = await relay.start_udp((host, 0), server.udp_address)
            ccfg = ClientConfig(server=host, port=tcp[1], udp_port=udp[1], methods=(SETUP["method"],),
                                width=SETUP["width"], height=SETUP["height"], display_hz=SETUP["client_fps"],
                                trace=SETUP["trace"], duration_s=duration_s, out_dir=out, save_images=True,
                                nack_max_tries=int(recovery.get("nack_max_tries", 3)),
                                jitter_timeout_ms=float(recovery.get("jitter_timeout_ms", 300.0)),
                                playout_delay_ms=float(recovery.get("playout_delay_ms", 0.0)),
                                stall_frames=float(recovery.get("stall_frames", 6.0)), metrics_interval_s=0)
            run = asyncio.create_task(asyncio.wait_for(LiveClient(ccfg).run(), duration_s + 30))
            while not server.sessions and not run.done():   # keep the session: it unregisters at Bye
                await asyncio.sleep(0.01)
            sessions = list(server.sessions.values())
            result = await run
            server_counters = dict(sessions[0].counters) if sessions else {}
        finally:
            await relay.wait_tcp_idle(1.0)
            await relay.close()
            serve.cancel()
            await asyncio.gather(serve, return_exceptions=True)
    out_s = session_summary(result.counters, server_counters, result.rows)
    # the impairment's losses only: sends that failed once the client had left are counted apart
    out_s["packets_lost"] = relay.stats().downlink.packets_dropped
    out_s["packets_undeliverable"] = relay.stats().downlink.packets_undeliverable
    out_s["frames_skipped_late"] = server_counters.get("frames_skipped_late", 0)
    out_s["late_ticks"] = result.counters.get("late_ticks", 0)
    out_s["rtp_packets"] = server_counters.get("rtp_packets", 0)
    out_s["timer_lag_ms_mean"] = result.counters.get("timer_lag_ms_mean", math.nan)
    out_s["timer_lag_ms_max"] = result.counters.get("timer_lag_ms_max", math.nan)
    return out_s


def run_live(network: str, recovery: dict[str, Any], duration_s: float, seed: int, renderer: Any = None) -> dict[str, Any]:
    """One live session of the cell on loopback through the relay; its summary (the recording scored)."""
    with tempfile.TemporaryDirectory(prefix="sr-agree-") as tmp:
        out = Path(tmp)
        s = asyncio.run(_live(network, recovery, duration_s, seed, out))
        scored = score_recording(out, renderer=renderer, flip_every=0)
    s["mean_psnr_db"] = scored.get("mean_psnr_db", math.nan)
    s["mean_update_age_ms"] = scored.get("mean_update_age_ms", math.nan)
    return s


def run_cell(impairment: str, recovery: str, duration_s: float = 8.0, seed: int = 1, renderer: Any = None) -> dict[str, Any]:
    """Both modes for one cell; a row with ``<column>_vt`` and ``<column>_live`` for :data:`COMPARED`."""
    network, rec = IMPAIRMENTS[impairment], RECOVERY[recovery]
    t0 = time.perf_counter()
    vt = run_virtual(network, rec, duration_s, seed, renderer)
    t1 = time.perf_counter()
    live = run_live(network, rec, duration_s, seed, renderer)
    t2 = time.perf_counter()
    row: dict[str, Any] = {"impairment": impairment, "recovery": recovery, "network": network, "seed": seed,
                           "duration_s": duration_s, "vt_s": t1 - t0, "live_s": t2 - t1,
                           "live_frames_skipped_late": live.get("frames_skipped_late", 0),
                           "live_late_ticks": live.get("late_ticks", 0),
                           "live_timer_lag_ms_mean": live.get("timer_lag_ms_mean", math.nan),
                           "live_timer_lag_ms_max": live.get("timer_lag_ms_max", math.nan)}
    for k in COMPARED:
        row[f"{k}_vt"] = vt.get(k, math.nan)
        row[f"{k}_live"] = live.get(k, math.nan)
    log.info("agreement %s / %s: shown %.1f vs %.1f %%, NACKs %s vs %s, keyframes %s vs %s", impairment, recovery,
             row["shown_pct_vt"], row["shown_pct_live"], row["nacks_vt"], row["nacks_live"], row["keyframes_vt"],
             row["keyframes_live"])
    return row


def within_targets(row: dict[str, Any]) -> dict[str, bool]:
    """The issue's targets for one cell: frames shown within 5 points; NACK and keyframe counts within 20 %
    (or within 2 of each other where the counts are that small)."""
    def close(k: str) -> bool:
        a, b = float(row[f"{k}_vt"]), float(row[f"{k}_live"])
        return abs(a - b) <= max(2.0, 0.2 * max(a, b))

    return {"shown": abs(float(row["shown_pct_vt"]) - float(row["shown_pct_live"])) <= 5.0,
            "nacks": close("nacks"), "keyframes": close("keyframes")}
