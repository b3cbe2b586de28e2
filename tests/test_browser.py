"""The page in a real browser (Debian's Chromium, driven by Playwright): video and atw sessions over WebRTC,
recorded by the page, posted back and scored against the ground truth like the headless client's recordings.

Skipped, with the reason, where Chromium or Playwright is missing (``.ci/run`` installs both).  Screenshots
of the canvas go to ``$SPLITRENDER_SCREENSHOTS`` when it is set (how ``docs/img/browser_*.png`` were made).
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import pytest

from splitrender.webrtc.driver import PageDriver, ServerProcess, browser_missing

pytestmark = [pytest.mark.slow, pytest.mark.skipif(browser_missing() is not None, reason=str(browser_missing()))]

DELAY = "delay 50ms"
"""The relay between page and server: 50 ms each way (100 ms round trip)."""


@pytest.fixture(scope="module")
def driver():
    with PageDriver() as d:
        yield d


def _screenshot(driver: PageDriver, tmp: Path, name: str) -> None:
    path = tmp / f"browser_{name}.png"
    driver.screenshot(path)
    assert path.stat().st_size > 1000
    dest = os.environ.get("SPLITRENDER_SCREENSHOTS")
    if dest:
        Path(dest).mkdir(parents=True, exist_ok=True)
        shutil.copy(path, Path(dest) / path.name)


def _session(driver: PageDriver, server: ServerProcess, out: Path, method: str,
             duration_s: float = 5.0) -> tuple[dict, dict, dict]:
    """One session (5 s) at 320x180 (the turn trace); returns the page's result, the scored summary, counters."""
    from splitrender.client.score import score_recording

    res = driver.session(server.url, method, trace="turn", duration_s=duration_s, record_every=4)
    assert res["ok"], (res, list(driver.console), list(server.log)[-20:])
    d = out / res["session_id"]
    # every row the page drew is in the recording, and the page drew from the start to the end of the session with
    # no stall: not a display rate (measured 184-300 rows in 5 s, 37-60 Hz, by load), which is the machine's
    assert res["saved"]["rows"] == res["rows"] > 0
    from splitrender.experiments.store import read_csv

    ts = [float(r["t_s"]) for r in read_csv(d / "frames.csv")]
    assert ts[0] < 0.5 and ts[-1] > 4.5, (ts[0], ts[-1])
    assert max(b - a for a, b in zip(ts, ts[1:])) < 1.0, "the page stopped drawing for a second or more"
    summary = score_recording(d, flip_every=0)
    counters = json.loads((d / "counters.json").read_text())
    return res, summary, counters


REACH_DEG = 10.0
"""ATW's reach: its 1.3x overscan holds 6.9 deg (vertically) to 7.4 deg (horizontally) beyond the display's field of
view at 320x180 and 60 deg, and past that it smears the edge pixels over a margin."""


def _scores_within_reach(session_dir: Path, reach_deg: float = REACH_DEG) -> list[float]:
    """PSNR of the scored rows whose shown frame was rendered at most ``reach_deg`` of rotation from the pose the row
    drew.  The page sends its pose on each tick it draws, so a frame's pose is the one a row ``motion_to_photon_ms``
    earlier drew (by ``t_s``)."""
    import csv
    import math

    import numpy as np

    with open(session_dir / "frames.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    drawn = np.array([float(r["t_s"]) * 1000 for r in rows])
    quat = lambda r: np.array([float(r[k]) for k in ("qx", "qy", "qz", "qw")])  # noqa: E731
    out = []
    for r in rows:
        if not r["psnr_db"] or not r["motion_to_photon_ms"]:
            continue
        at = float(r["t_s"]) * 1000 - float(r["motion_to_photon_ms"])
        k = int(np.argmin(np.abs(drawn - at)))
        # both columns are rounded to 0.1 ms or finer (the page's clock is coarser)
        assert abs(drawn[k] - at) < 1.0, ("no row drew the pose of the frame shown", r["frame"], at, drawn[k])
        sent = rows[k]
        angle = math.degrees(2 * math.acos(min(1.0, abs(float(quat(r) @ quat(sent))))))
        if angle <= reach_deg:
            out.append(float(r["psnr_db"]))
    return out


def test_video_and_atw_in_the_browser_are_scored_and_atw_beats_video_under_delay(driver, tmp_path):
    out = tmp_path / "rec"
    with ServerProcess(["--scene", "minimal", "--methods", "video,atw", "--out", str(out),
                        "--webrtc-network", DELAY]) as server:
        scores, reach = {}, {}
        for method in ("video", "atw"):
            # measured: 98-100 % of the server's frames decoded (137-147 of 139-149 idle; 57 of 60 with the suite
            # running beside it: how many the server sends in 5 s is the machine's rate, so only enough to score,
            # and a session that sent fewer than 25 is run again for longer: at load 15-20, 17 and 18 in 5 s).
            # What arrived is the transport's; what was decoded by the end also the page's speed: at load 13-22 the
            # jitter buffer still held 5-10 received frames (64 decoded of 74 sent, 6 of 11 received)
            for duration_s in (5.0, 10.0, 20.0):
                res, summary, counters = _session(driver, server, out, method, duration_s=duration_s)
                if counters["frames_sent"] >= 25:
                    break
            _screenshot(driver, tmp_path, method)
            sent = counters["frames_sent"]
            st = res["stats"]
            assert sent >= 25 and st["framesReceived"] >= 0.9 * sent, (method, st, sent, duration_s)
            assert st["framesDecoded"] <= st["framesReceived"] and st["framesDecoded"] >= 0.5 * sent, (method, st, sent)
            rec = json.loads((out / res["session_id"] / "recording.json").read_text())
            assert rec["method"] == method and rec["client"]["kind"] == "browser" and rec["network"] == DELAY
            assert summary["frames"] == res["rows"]
            # the relay's 50 ms each way is in every frame's age (measured 119-133 ms on average)
            assert summary["mean_update_age_ms"] > 100, summary["mean_update_age_ms"]
            assert counters["relay_down_in"] > 0 and counters["relay_up_in"] > 0
            scores[method] = summary["mean_psnr_db"]
            reach[method] = _scores_within_reach(out / res["session_id"])
    # Compared where ATW can correct: the rows whose frame's pose is within its reach of the pose drawn.  On a loaded
    # machine frames grow 1-2 s old (at load 14-17: 10 of 52-64 scored rows within 10 deg), and past its overscan ATW
    # smears the reference's edge pixels or, turned away from it, shows black (3-5 dB rows) while video's stale
    # picture scores 15-18: over every row ATW then loses (13.2 against 16.3 dB) where within reach it wins (23.6
    # against 17.5).  At load 10-13: 26-35 rows within reach, atw 25.3-27.7 dB, video 19.7-21.8 (over every row
    # 17.2-18.6 against 16.6-18.2).  Idle over every row: video 21.7-22.5 dB, atw 25.4-25.5
    n = {m: len(v) for m, v in reach.items()}
    assert min(n.values()) >= 5, (n, scores)
    mean = {m: sum(v) / len(v) for m, v in reach.items()}
    # a black or garbled picture scores 5-10 dB here: video above 15 says the frames shown are the server's
    assert mean["video"] > 15.0, (mean, n, scores)
    assert mean["atw"] > mean["video"] + 1.0, (mean, n, scores)


def test_browser_statistics_agree_with_the_server(driver, tmp_path):
    """getStats in the page against the server's counters, with 3 % of the downlink lost: every NACK the page
    sends reaches the server (the uplink loses nothing), and the packets the page counts are the server's.  The
    session adapts (``--adapt rate``): the page's REMB reports reach the core, and every frame is coded within the
    estimate the core holds (that the core follows REMB: ``test_adapt.py``)."""
    from splitrender.experiments.store import read_csv

    out = tmp_path / "rec"
    with ServerProcess(["--scene", "minimal", "--methods", "video", "--out", str(out), "--adapt", "rate",
                        "--webrtc-network", "up: delay 10ms; down: delay 10ms loss 3%"]) as server:
        res, summary, c = _session(driver, server, out, "video", duration_s=8.0)
    # Chromium's first REMB comes after about 5 s (none in 5 s sessions, 7-11 in 8 s, measured)
    assert c["estimates_received"] > 0, c
    rows = read_csv(out / res["session_id"] / "updates.csv")
    # every page Feedback the core took has its row, as the RTP front door writes them (issue 47)
    feedback = read_csv(out / res["session_id"] / "feedback.csv")
    assert len(feedback) >= c["feedback"] > 0 and all(isinstance(r["server_us"], (int, float)) and r["server_us"] > 0 for r in feedback), (len(feedback), c)
    targets = [r["cc_target_kbps"] for r in rows]
    # the estimate left GCC's start for the page's (measured: 100-190 kbit/s on this link) and stayed in bounds
    assert targets[0] == 300.0 and any(t != 300.0 for t in targets) and all(100.0 <= t <= 50_000.0 for t in targets), targets
    # and no frame was coded above the highest estimate so far (a report may land between a frame's order and its row):
    # what its target asks of the encoder, the target times the encoder's miss as learnt when it was set (the row
    # before's: a row shows the miss its own frame then taught).  A target alone may pass the estimate by design where
    # the encoder undershoots (pipeline/adapt.py, 3: measured 306-317 kbit/s targets at a miss of 0.84-0.95 under a
    # 300 kbit/s estimate)
    miss = [1.0] + [r["adapt_color_miss"] for r in rows[:-1]]
    over = [(k, r["adapt_color_kbps"], miss[k], max(targets[:k + 1])) for k, r in enumerate(rows)
            if r["adapt_color_kbps"] * miss[k] > max(targets[:k + 1])]
    assert not over, over[:5]
    st = res["stats"]
    # the page sends NACKs for the lost packets, and reads its statistics before it says bye: the server has
    # every NACK counted (measured: equal in 4 runs of 5; in the fifth, read after bye, one short)
    assert st["nackCount"] > 0 and c["nacks_received"] >= st["nackCount"], (st, c)
    assert c["nacks_received"] - st["nackCount"] <= 2, (st, c)
    assert 0 <= c["plis"] - st["pliCount"] <= 1, (st, c)
    assert c["nacked_packets"] > 0
    # packets: libwebrtc counts a packet recovered by retransmission as received, so it counts every packet sent
    # but those still in flight when it read its statistics (measured: 1-6 of 787-813 short) and, as lost, the
    # ones that were missing at first (measured: equal to the packets NACKed, 23-28, or one fewer).  It counts every
    # copy it receives: on a loaded machine, where a resend comes late, the page NACKs the packet again and may then
    # receive it twice, so the NACKed packets beyond the lost ones bound the copies beyond those sent (measured at
    # load 13-15: 85 received of 82 sent, 5 lost, 10 NACKed; 91 of 79, 2 lost, 17 NACKed; aiortc's packetsSent counts
    # no resend)
    repeats = max(0, c["nacked_packets"] - st["packetsLost"])
    assert c["rtp_packets"] - 12 <= st["packetsReceived"] <= c["rtp_packets"] + repeats, (st, c)
    assert 0 < st["packetsLost"] <= c["relay_down_dropped"], (st, c)
    assert c["nacked_packets"] >= st["packetsLost"] - 5, (st, c)        # every packet missing at first is NACKed
    # frames: none decoded that the server did not send, none of the IDRs missed
    assert st["framesDecoded"] <= c["frames_sent"] and st["keyFramesDecoded"] <= c["keyframes"]
    # what arrived is the transport's (NACKs recover the 3 % lost: 82 and 84 received of 84 and 85 sent at load 16);
    # what was decoded by the time the page read its statistics also the page's speed: 98-100 % idle, 92-96 % at load
    # 16, 86-88 % at load 15-20 (60 of 68, 31 of 36 sent: the jitter buffer still held received frames)
    assert st["framesReceived"] >= 0.9 * c["frames_sent"], (st, c)
    assert st["framesDecoded"] <= st["framesReceived"] and st["framesDecoded"] >= 0.75 * c["frames_sent"], (st, c)
    assert summary["nacks"] == 0           # the headless client's columns stay theirs: the page's are browser_*
    assert c["browser_nackCount"] == st["nackCount"]


def test_a_page_that_breaks_the_protocol_ends_its_own_session_only(driver, tmp_path):
    """Two pages stream; one sends garbage on its pose channel: it gets an error naming what was wrong and its
    session ends, while the other keeps streaming to its end."""
    from splitrender.webrtc.driver import VIEWPORT

    with ServerProcess(["--scene", "minimal", "--methods", "video", "--out", str(tmp_path)]) as server:
        bad = driver.browser.new_page(viewport=VIEWPORT)
        # the bad page's session outlasts the good page's start (a loaded CI machine took more than its 4 s to start
        # the second page, and the first page's channels had closed before its garbage was sent); the garbage ends it
        bad.goto(f"{server.url}?method=video&trace=turn&duration=60&width=320&height=180&autostart=1")
        bad.wait_for_function("() => window.splitrender.state.phase === 'streaming'", timeout=60_000)
        good = driver.browser.new_page(viewport=VIEWPORT)
        good.goto(f"{server.url}?method=video&trace=turn&duration=4&width=320&height=180&autostart=1")
        good.wait_for_function("() => window.splitrender.state.phase === 'streaming'", timeout=60_000)
        bad.evaluate("() => window.splitrender.send('pose', '{\"type\": \"pose\", \"seq\": 1}')")
        res_bad = bad.evaluate("() => window.splitrender.done")
        res_good = good.evaluate("() => window.splitrender.done")
        bad.close()
        good.close()
        log = "\n".join(server.log)
    assert not res_bad["ok"] and "pose message.q: expected a list of 4 numbers, got None" in res_bad["error"], res_bad
    assert "pose message.q: expected a list of 4 numbers" in log
    assert res_good["ok"] and res_good["stats"]["framesDecoded"] > 60, res_good


def test_sas_in_the_browser_draws_the_atlas_on_its_geometry(driver, tmp_path):
    """``sas``: the atlas comes as the video track and the PVS patches as vertex slots on the meta channel; at a
    still pose on loopback every drawn frame matches the ground truth closely (the page's geometry, uv and
    Catmull-Rom lookup are the headless client's)."""
    import numpy as np

    from splitrender.client.score import read_frames

    out = tmp_path / "rec"
    with ServerProcess(["--scene", "minimal", "--methods", "sas", "--out", str(out)]) as server:
        res = driver.session(server.url, "sas", trace="static", duration_s=5.0, record_every=4)
        assert res["ok"], (res, list(driver.console), list(server.log)[-20:])
        _screenshot(driver, tmp_path, "sas")
    from splitrender.client.score import score_recording

    d = out / res["session_id"]
    score_recording(d, flip_every=0)
    c = json.loads((d / "counters.json").read_text())
    # what is drawn against what was sent (the frame count only has to leave something to score): all decoded idle;
    # 55 of 79 sent in a clean-clone CI run at 20d3fa9 beside the stress suite, where a slowed decoder still held the
    # last frames when the 5 s session ended
    assert c["frames_sent"] >= 4 and res["stats"]["framesDecoded"] >= 0.6 * c["frames_sent"], (res["stats"], c)
    assert c["sas_slot_bytes"] > 0 and c["sas_meta_bytes"] > 0
    rows = read_frames(d / "frames.csv")
    scored = [r for r in rows if np.isfinite(r.get("psnr_db", np.nan))]
    first = next((i for i, r in enumerate(scored) if r["update_frame_id"] >= 0), len(scored))
    drawn = np.array([r["psnr_db"] for r in scored[first:]])
    # every scored tick after the first drawn one shows an update (none goes blank again), and each matches the ground
    # truth: measured 60 drawn frames scored idle, mean 41.9 dB, the worst 41.7 dB; 19 and then 3 (42.6-43.7 dB) in
    # clean-clone CI runs beside the background stress suite, where the page's display ticks come slower.  How many is
    # the display rate's business; what was drawn against what was sent is checked above
    assert all(r["update_frame_id"] >= 0 for r in scored[first:]), [r["update_frame_id"] for r in scored]
    assert drawn.size >= 2 and drawn.min() > 40.0, (drawn.size, drawn.min() if drawn.size else None)


def test_a_browser_session_under_adapt_full_moves_its_operating_point(driver, tmp_path):
    """``serve --webrtc --adapt full`` (issue 47): the browser door drives the server core with the knobs a page can
    follow (video's resolution ``scale``): the operating point moves and the page decodes the smaller video, and the
    page's REMB reports, passed on by the aiortc adapter, set the encoder's rate, behind a relay whose downlink falls
    from 3 to 0.12 Mbit/s after 6 s (a step trace).  Asserted on what the server recorded (``updates.csv``,
    ``counters.json``), not on rates.

    Measured at load 10-17 (four 12-18 s runs, minimal scene, 320x180; the server, slowed, sent 3 frames a
    second): the point moved to 1 (scale 0.75) or 2 (0.5) at 3-4 s, under GCC's 300 kbit/s start (which the quality
    model prefers at a lower resolution for 320x180 video), and in two runs on to 2 at the first REMB; Chromium's
    first REMB came after 4-5 s and said 100 kbit/s, and the colour's target fell from 270 to 90 kbit/s.  A run
    without the fall (50 Mbit/s) went the same way: on this machine the page's estimate sits at 100 kbit/s before the
    link falls (it rises only with what arrives), so the fall itself moves nothing here."""
    from splitrender.experiments.store import read_csv
    from splitrender.netsim.traces import step_trace, write_mahimahi

    trace = write_mahimahi(step_trace([(6.0, 3.0), (30.0, 0.12)]), tmp_path / "step.trace")
    net = tmp_path / "falls.toml"
    net.write_text(f'[uplink]\ndelay_ms = 10.0\n[downlink]\ndelay_ms = 10.0\ntrace_path = "{trace}"\nlimit_packets = 60\n')
    out = tmp_path / "rec"
    with ServerProcess(["--scene", "minimal", "--methods", "video", "--out", str(out), "--adapt", "full",
                        "--webrtc-network", str(net)]) as server:
        res = driver.session(server.url, "video", trace="turn", duration_s=12.0, record_every=4)
        assert res["ok"], (res, list(driver.console), list(server.log)[-20:])
    d = out / res["session_id"]
    c = json.loads((d / "counters.json").read_text())
    rows = read_csv(d / "updates.csv")
    points = [int(r["adapt_point"]) for r in rows]
    assert c["point_moves"] >= 1, c
    # the rows name the points their frames were made at: from the richest, to a lower one at a smaller video
    assert points[0] == 0 and max(points) >= 1, points
    assert min(float(r["adapt_knob_scale"]) for r in rows) < 1.0, [r["adapt_knob_scale"] for r in rows]
    # the page's estimate reached the core, and the colour's target followed it down from what GCC's start gave
    first = next((k for k, r in enumerate(rows) if r["cc_target_kbps"] != 300.0), None)
    assert c["estimates_received"] > 0 and first is not None, (c, [r["cc_target_kbps"] for r in rows])
    color = [float(r["adapt_color_kbps"]) for r in rows]
    assert min(color[first:]) < min(color[:first]), (first, color)
    # the page decoded frames across the resolution changes (measured 52 of 53, 41 of 44, and 20 of 29 sent at load
    # 17; idle, 166 of 291: a server at full rate sends more than the fallen link carries, and the relay drops the
    # rest, so no share of what was sent holds both ways; a count does)
    assert res["stats"]["framesDecoded"] >= 20, (res["stats"], c)
