"""The one recording writer (``splitrender.pipeline.recording``): what a client's folder holds while a session runs,
after it ends, and after it is killed; and a server's per-session logs."""

from __future__ import annotations

import csv
import json
import math

import numpy as np

from splitrender.pipeline.recording import JOURNAL, ClientRecording, SessionLogs, iter_journal, manifest, save_image, write_run


def _csv(path):  # type: ignore[no-untyped-def]
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def test_a_recording_keeps_its_rows_in_the_journal_until_it_is_finished(tmp_path):
    d = tmp_path / "rec"
    d.mkdir()
    (d / "frames.csv").write_text("stale\n")          # an earlier session's table goes at the start
    rec = ClientRecording(d)
    assert not rec.started
    rec.start({"method": "video"})
    assert rec.started and not (d / "frames.csv").exists()
    assert json.loads((d / "recording.json").read_text()) == {"method": "video", "complete": False}
    rows = [{"frame": i, "psnr": float(i) if i else math.nan} for i in range(5)]
    for r in rows:
        rec.append(r)
    rec.finish({"method": "video", "complete": True}, {"late_ticks": 2}, rows[-2:])   # the journal wins over rows
    got = _csv(d / "frames.csv")
    assert [int(r["frame"]) for r in got] == [0, 1, 2, 3, 4] and got[0]["psnr"] == ""
    assert json.loads((d / "recording.json").read_text())["complete"] is True
    assert json.loads((d / "counters.json").read_text()) == {"late_ticks": 2}
    assert not (d / JOURNAL).exists() and rec.rows == 5


def test_a_killed_client_leaves_a_journal_that_reads_back_without_its_torn_line(tmp_path):
    rec = ClientRecording(tmp_path)
    rec.start({"method": "sas"})
    for i in range(3):
        rec.append({"frame": i, "age": None if i == 1 else 10.0 * i})
    rec._journal.flush()                               # what the periodic flush would have written  # type: ignore[union-attr]
    with open(tmp_path / JOURNAL, "a") as f:
        f.write('{"frame": 3, "ag')                    # killed mid-line
    rows = list(iter_journal(tmp_path / JOURNAL))
    assert [r["frame"] for r in rows] == [0, 1, 2]
    assert math.isnan(rows[1]["age"]) and rows[2]["age"] == 20.0
    assert json.loads((tmp_path / "recording.json").read_text())["complete"] is False


def test_a_recording_uploaded_whole_is_written_from_its_rows(tmp_path):
    ClientRecording(tmp_path / "page").finish({"method": "atw", "complete": True}, {"frames": 2},
                                              [{"frame": 0}, {"frame": 1, "extra": 1.5}])
    got = _csv(tmp_path / "page" / "frames.csv")
    assert [r["frame"] for r in got] == ["0", "1"] and got[1]["extra"] == "1.5" and got[0]["extra"] == ""
    assert not (tmp_path / "page" / JOURNAL).exists()


def test_images_are_saved_whole_with_their_holes(tmp_path):
    color = np.arange(2 * 3 * 3, dtype=np.uint8).reshape(2, 3, 3)
    holes = np.array([[True, False, False], [False, False, True]])
    save_image(tmp_path, 7, color, holes)
    save_image(tmp_path, 8, color, None)
    with np.load(tmp_path / "images" / "000007.npz") as z:
        assert (z["color"] == color).all() and (z["holes"] == holes).all()
    with np.load(tmp_path / "images" / "000008.npz") as z:
        assert set(z.files) == {"color"}


def test_session_logs_fix_their_columns_and_write_counters_only_for_a_session_that_logged(tmp_path):
    logs = SessionLogs(tmp_path / "s1")
    logs.append("updates", {"frame_id": 0, "bytes": 10})
    logs.append("updates", {"frame_id": 1, "bytes": 12, "late_key": 5})      # a key beyond the first row's is left out
    logs.append("feedback", {"a": 1}, columns=("a", "b"))
    assert logs.rows("updates") == 2 and logs.rows("none") == 0
    logs.close({"frames_sent": 2, "method": "video"})
    assert _csv(tmp_path / "s1" / "updates.csv") == [{"frame_id": "0", "bytes": "10"}, {"frame_id": "1", "bytes": "12"}]
    assert _csv(tmp_path / "s1" / "feedback.csv") == [{"a": "1", "b": ""}]
    assert _csv(tmp_path / "s1" / "counters.csv") == [{"frames_sent": "2", "method": "video"}]
    quiet = SessionLogs(tmp_path / "s2")
    quiet.close({"frames_sent": 0})
    assert not (tmp_path / "s2").exists()
    none = SessionLogs(None)
    none.append("updates", {"frame_id": 0})
    none.close({"frames_sent": 1})
    assert none.rows("updates") == 0


def test_a_runs_frames_table_is_a_recordings_and_its_folder_is_written_in_one_place(tmp_path):
    """Issue 47: a virtual-time run's folder is written by the recording module too, its frames.csv the same bytes a
    client recording uploaded whole gets from the same rows."""
    rows = [{"frame": 0, "update_frame_id": -1, "psnr": math.nan}, {"frame": 1, "update_frame_id": 3, "psnr": 31.5}]
    shown, truth = np.zeros((2, 3, 3), np.uint8), np.full((2, 3, 3), 255, np.uint8)
    d = write_run(tmp_path / "run", rows, [{"frame_id": 3, "bytes": 900}], [{"client": 0, "frames": 2}],
                  "[run]\nmethod = \"video\"\n", [(1, shown, truth)])
    ClientRecording(tmp_path / "rec").finish({"complete": True}, {}, rows)
    assert (d / "frames.csv").read_bytes() == (tmp_path / "rec" / "frames.csv").read_bytes()
    assert _csv(d / "updates.csv") == [{"frame_id": "3", "bytes": "900"}]
    assert _csv(d / "summary.csv") == [{"client": "0", "frames": "2"}]
    assert (d / "config.toml").read_text().startswith("[run]")
    assert [p.name for p in (d / "images").iterdir()] == ["frame00001_client_vs_truth.png"]


def test_every_client_front_door_writes_the_manifest_the_scorer_reads():
    """The keys :func:`splitrender.client.score.score_recording` reads are the manifest's, whoever wrote it."""
    m = manifest("s1", "atw", {"overscan": 1.2}, "default", 60.0, 30, "walk", 320, 180, 60.0, 120.0, 2.0, True,
                 {"kind": "browser"}, complete=True, network="live")
    for key in ("method", "scene", "trace", "width", "height", "fov_y_deg", "server_fps", "display_hz", "duration_s",
                "images", "params", "session_id", "complete", "network"):
        assert key in m, key
    assert m["client"] == {"kind": "browser"} and m["params"] == {"overscan": 1.2}


def test_the_wall_clock_columns_of_update_rows_are_timing_columns() -> None:
    """Every column of an update row or its summary that carries a measured stage (make_frame's stages, the encoder's
    milliseconds) is one the store and the self-repeat comparisons leave out: two runs of one config differ there
    and nowhere else (shared_ms and mean_shared_server_ms were missing, and a sas run's rows differed in them)."""
    from types import SimpleNamespace

    from splitrender.experiments.store import is_timing_column
    from splitrender.pipeline.rows import update_row, updates_summary

    stages = {"shared_ms": 1e9 + 1, "produce_ms": 1e9 + 2}
    out = SimpleNamespace(total_wire_bytes=100, keyframe=False, wire_bytes={"color": 100})
    row = update_row(0, 0.0, out, SimpleNamespace(encode_ms=1e9 + 3), SimpleNamespace(expected_latency_s=0.05),
                     stages, ["color"], {})
    measured = {k for k, v in {**row, **updates_summary([row])}.items() if isinstance(v, float) and v > 1e9}
    assert measured == {"shared_ms", "server_ms", "encode_ms", "mean_shared_server_ms", "mean_server_ms",
                        "mean_encode_ms"}
    assert all(is_timing_column(k) for k in measured), sorted(k for k in measured if not is_timing_column(k))
