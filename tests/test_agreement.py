"""Virtual time against live: the same seeded session both ways at 2 % loss (the benchmark,
``benchmarks/bench_agreement.py``, holds the full grid), and virtual time repeating itself."""

from __future__ import annotations

import math

import pytest
from _load import slowdown_over

from splitrender.experiments.agreement import RECOVERY, run_cell, run_virtual, within_targets


def _simulated(row: dict) -> dict:  # type: ignore[type-arg]
    """``row`` less the wall-clock milliseconds (measured, so they differ run to run)."""
    keep = {}
    for k, v in row.items():
        if k.endswith("_ms") and k not in ("update_age_ms", "motion_to_photon_ms", "longest_freeze_ms", "longest_stall_ms",
                                           "mean_update_age_ms", "p95_update_age_ms", "mean_motion_to_photon_ms",
                                           "expected_latency_ms", "mean_expected_latency_ms", "cost_ms", "mean_cost_ms"):
            continue
        if k in ("config_key",):
            continue
        keep[k] = "nan" if isinstance(v, float) and math.isnan(v) else v
    return keep


@pytest.mark.slow
def test_patient_client_at_two_percent_loss_agrees_between_virtual_time_and_live() -> None:
    """The README's patient client (FEC, 300 ms playout delay, six NACK tries) at 2 % loss on both
    directions: frames shown within 5 points, keyframe counts within 20 % (or 2), NACK counts within 6, and the
    picture and its age close, in one seeded 8 s session run both ways.  Measured (seed 1, two runs): shown 100 /
    100 %, NACKs 1 / 0-4, keyframes 5 / 6, PSNR 19.0 / 17.9-18.0 dB, update age 328 / 327-329 ms; live varies
    with the machine, hence the PSNR and age bounds of 1.5 dB and 30 ms.  The age bound is an idle machine's,
    scaled by the slowdown measured just before and after the session (tests/_load.py): at load 15 here live
    read 7-22 ms above virtual time's 327.9 in eight runs, at b44aad1 and at 68b0ee2 alike, and one clean-clone
    CI run (the suite's two workers and its stress suite beside it) read 31.0."""
    before = slowdown_over(1.0)
    row = run_cell("loss 2%", "patient", duration_s=8.0, seed=1)
    slowdown = max(before, slowdown_over(1.0))
    met = within_targets(row)
    assert met["shown"] and met["keyframes"], (met, row)
    # NACKs: the benchmark's target is within 2 (idle here: 1 / 1-2 in two runs), but live NACKs what parity has not
    # rebuilt by the time its timer fires, and a loaded machine delivers parity later: with a second pytest beside
    # the suite, live sent 4 or more against virtual time's 1.  The test holds the count to what loss explains.
    assert abs(row["nacks_vt"] - row["nacks_live"]) <= max(6, 0.2 * max(row["nacks_vt"], row["nacks_live"])), row
    assert row["shown_pct_vt"] >= 95 and row["shown_pct_live"] >= 95, row
    assert abs(row["mean_psnr_db_vt"] - row["mean_psnr_db_live"]) < 1.5, row
    assert abs(row["mean_update_age_ms_vt"] - row["mean_update_age_ms_live"]) < 30 * slowdown, (slowdown, row)
    # both lost packets and both got most of them back, by parity or by NACK.  Live splits them between the two
    # by timing: two runs here rebuilt 21 of 27 and 23 of 29 from parity and resent 2 and 6; one CI run under
    # load rebuilt only 10 of 25 from parity and still showed every frame.
    assert row["packets_lost_vt"] > 5 and row["packets_lost_live"] > 5, row
    assert row["fec_recovered_vt"] >= 0.5 * row["packets_lost_vt"], row
    assert row["fec_recovered_live"] > 0, row
    assert row["fec_recovered_live"] + row["retransmitted_live"] >= 0.5 * row["packets_lost_live"], row


def test_virtual_time_with_the_patient_options_repeats_itself_bit_for_bit() -> None:
    """Everything on the simulated clock (frames shown, NACKs, PLIs, bytes, scores) is the same for the
    same seed: the session cores draw their RTCP intervals and SSRCs from the run's seed."""
    runs = []
    for _ in range(2):
        from splitrender.sim.config import RunConfig
        from splitrender.sim.runner import VirtualTimeRun

        rec = RECOVERY["patient"]
        cfg = RunConfig(method="video", scene="minimal", trace="walk", network="delay 20ms 5ms loss 3%", width=160,
                        height=90, server_fps=15, client_fps=30, duration_s=3.0, seed=7, flip_every=0, mtu_bytes=300,
                        fec=True, playout_delay_ms=rec["playout_delay_ms"], nack_max_tries=rec["nack_max_tries"],
                        jitter_timeout_ms=rec["jitter_timeout_ms"], stall_frames=rec["stall_frames"])
        runs.append(VirtualTimeRun(cfg).run())
    a, b = runs
    assert a.summary["packets_lost"] > 0 and a.summary["fec_recovered"] > 0, a.summary
    assert _simulated(a.summary) == _simulated(b.summary)
    assert [_simulated(r) for r in a.frames] == [_simulated(r) for r in b.frames]
    assert [_simulated(r) for r in a.updates] == [_simulated(r) for r in b.updates]


def test_agreement_summaries_use_one_definition() -> None:
    """A virtual-time summary carries the session-summary columns the live side is scored with."""
    s = run_virtual("delay 20ms loss 5%", RECOVERY["nack"], 2.0, seed=3)
    for k in ("shown_pct", "longest_freeze_ms", "nacks", "keyframe_requests", "keyframes", "retransmitted", "packets_lost"):
        assert k in s, k
    assert s["packets_lost"] > 0 and s["nacks"] > 0 and s["retransmitted"] > 0, s
