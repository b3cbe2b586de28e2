"""``benchmarks/peer_quasar.py`` without QUASAR (issue 38): what it reads from QUASAR's logs, the camera path and scene
file it gives both tools, the command lines, the byte table, the scoring, and how it stops when the build is missing.

QUASAR is never built here; the runs themselves need its build and are the benchmark's business."""

from __future__ import annotations

import json
import math
import os
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

import peer_quasar as pq  # noqa: E402

from splitrender.scene.pose import quat_to_matrix3  # noqa: E402
from splitrender.scene.trace import CameraTrace, load_quasar_path  # noqa: E402

SEP = "======================================================"


def spd(msg: str, colour: bool = False) -> str:
    """A line as QUASAR's spdlog pattern ``[%H:%M:%S] [%^%L%$] %v`` writes it (with colour on a terminal)."""
    level = "\x1b[32mI\x1b[m" if colour else "I"
    return f"[12:34:56] [{level}] {msg}"


def qr_log(colour: bool = False) -> str:
    lines = ["Loading scene: /w/scene.json"]
    for kind, mb, n in (("RefFrame", "0.012", 1234), ("ResFrame", "0.004", 300), ("ResFrame", "0.005", 310)):
        lines += [SEP, f"Rendering Time ({kind}): 3.210ms", f"Create Proxies Time ({kind}): 1.000ms",
                  f"  Gen Quad Map Time ({kind}): 0.500ms", f"Compress Time ({kind}): 0.700ms",
                  f"Frame Size: {mb}MB", f"Num Proxies: {n}Proxies", "Client Render Time: 1.100ms",
                  "Client Render Time: 0.900ms"]
    lines += ["Pose Error:", "  Pos (0.05\u00b10.02,[0.0,0.10])m", "  Rot (1.20\u00b10.50,[0.1,2.50])\u00b0",
              "  RTT (100.50\u00b111.20)ms"]
    return "\n".join(spd(x, colour) for x in lines) + "\n"


# ------------------------------------------------------------------------------------------ QUASAR's log


def test_parse_qr_log_frames_kinds_bytes_and_pose_errors() -> None:
    log = pq.parse_quasar_log(qr_log())
    assert [f["kind"] for f in log.frames] == ["reference", "residual", "residual"]
    assert [f["bytes"] for f in log.frames] == [0.012 * 2**20, 0.004 * 2**20, 0.005 * 2**20]   # MB = 2**20 bytes
    assert [f["proxies"] for f in log.frames] == [1234, 300, 310]
    assert log.client_frames == 6
    assert (log.pos_err_m, log.rot_err_deg, log.rtt_ms) == (0.05, 1.20, 100.50)


def test_parse_log_strips_colour_codes_and_carriage_returns() -> None:
    plain = pq.parse_quasar_log(qr_log())
    coloured = pq.parse_quasar_log(qr_log(colour=True).replace("\n", "\r\n"))
    assert coloured.frames == plain.frames and coloured.rtt_ms == plain.rtt_ms
    assert pq.clean_line("[12:00:00] [\x1b[33mW\x1b[m] Frame Size: 1.500MB") == "Frame Size: 1.500MB"


def test_parse_qs_log_has_no_frame_kind() -> None:
    text = "\n".join(spd(x) for x in (SEP, "Rendering Time: 9.000ms", "Frame Size: 0.250MB", "Num Proxies: 40000Proxies",
                                      SEP, "Rendering Time: 9.000ms", "Frame Size: 0.251MB", "Num Proxies: 40100Proxies"))
    log = pq.parse_quasar_log(text)
    assert [f["kind"] for f in log.frames] == [None, None]
    assert [f["proxies"] for f in log.frames] == [40000, 40100]
    b = pq.quasar_bytes(log)
    assert b["bytes_quasar"] == pytest.approx(0.2505 * 2**20)
    assert b["bytes_quasar_reference"] is None and b["bytes_quasar_residual"] is None and b["bytes_ours"] is None


def test_parse_atw_log_counts_frames_but_no_bytes() -> None:
    text = "\n".join(spd(x) for x in (SEP, "Rendering Time: 2.000ms", "Client Render Time: 0.400ms",
                                      SEP, "Rendering Time: 2.100ms", "Client Render Time: 0.400ms"))
    log = pq.parse_quasar_log(text)
    assert len(log.frames) == 2 and log.client_frames == 2
    assert pq.quasar_bytes(log) == {"server_frames": 2, "bytes_ours": None, "bytes_quasar": None,
                                    "bytes_quasar_reference": None, "bytes_quasar_residual": None, "proxies": None,
                                    "proxies_reference": None, "proxies_residual": None}


def test_quasar_bytes_mean_over_every_frame_and_by_kind() -> None:
    b = pq.quasar_bytes(pq.parse_quasar_log(qr_log()))
    assert b["server_frames"] == 3
    assert b["bytes_quasar"] == pytest.approx((0.012 + 0.004 + 0.005) / 3 * 2**20)
    assert b["bytes_quasar_reference"] == pytest.approx(0.012 * 2**20)
    assert b["bytes_quasar_residual"] == pytest.approx(0.0045 * 2**20)
    assert b["proxies"] == pytest.approx((1234 + 300 + 310) / 3)
    assert b["proxies_reference"] == 1234 and b["proxies_residual"] == pytest.approx(305)


# ------------------------------------------------------------------------------------------ bytes both ways


def test_bytes_table_both_ways_from_parsed_numbers() -> None:
    atw_log = pq.parse_quasar_log("\n".join(spd(x) for x in (SEP, "Rendering Time: 2.000ms")))
    qs_log = pq.parse_quasar_log("\n".join(spd(x) for x in (SEP, "Rendering Time: 9.0ms", "Frame Size: 0.100MB",
                                                            "Num Proxies: 500Proxies")))
    ours = {
        "atw": [{"bytes": 900}, {"bytes": 1100}],
        "quasar": [{"bytes": 10_000, "srv_quasar_bytes": 6000.0, "srv_quasar_proxies": 100.0, "srv_reference": 1.0},
                   {"bytes": 4000, "srv_quasar_bytes": 2000.0, "srv_quasar_proxies": 50.0, "srv_reference": 0.0},
                   {"bytes": 4000, "srv_quasar_bytes": 1000.0, "srv_quasar_proxies": 30.0, "srv_reference": 0.0}],
        "quadstream": [{"bytes": 50_000, "srv_quasar_bytes": 80_000.5, "srv_quasar_proxies": 9000.0, "srv_reference": 1.0}],
    }
    rows = pq.bytes_table({"atw": atw_log, "quasar": pq.parse_quasar_log(qr_log()), "quadstream": qs_log}, ours)
    assert [(r["tool"], r["method"]) for r in rows] == [("QUASAR", m) for m in pq.METHODS] + [("splitrender", m) for m in pq.METHODS]
    by = {(r["tool"], r["method"]): r for r in rows}
    assert by["QUASAR", "quasar"]["program"] == "qr_simulator"
    assert by["splitrender", "quadstream"]["program"] == "quads variant=quadstream"
    # QUASAR's frames: only their own count; atw_simulator counts nothing
    assert all(by["QUASAR", m]["bytes_ours"] is None for m in pq.METHODS)
    assert by["QUASAR", "atw"]["bytes_quasar"] is None and by["QUASAR", "atw"]["server_frames"] == 1
    assert by["QUASAR", "quadstream"]["bytes_quasar"] == pytest.approx(0.1 * 2**20)
    # ours: every stream, and as QUASAR counts
    assert by["splitrender", "atw"]["bytes_ours"] == 1000 and by["splitrender", "atw"]["bytes_quasar"] is None
    q = by["splitrender", "quasar"]
    assert (q["bytes_ours"], q["bytes_quasar"], q["proxies"]) == (6000, 3000, 60)
    assert (q["bytes_quasar_reference"], q["bytes_quasar_residual"]) == (6000, 1500)
    s = by["splitrender", "quadstream"]
    assert s["bytes_quasar"] == 80_000.5 and s["bytes_quasar_reference"] is None   # every QuadStream frame is whole


def test_bytes_table_leaves_out_what_was_not_run() -> None:
    rows = pq.bytes_table({}, {"quasar": [{"bytes": 1, "srv_quasar_bytes": 1.0}]})
    assert [(r["tool"], r["method"]) for r in rows] == [("splitrender", "quasar")]
    assert rows[0]["proxies"] is None


# ------------------------------------------------------------------------------------------ camera path and scene


def trace_with_roll() -> CameraTrace:
    from splitrender.scene.pose import quat_from_euler_deg

    t = np.arange(0, 121) / 120.0
    pos = np.stack([0.5 * t, 1.6 + 0.01 * np.sin(6 * t), -0.2 * t], 1)
    q = np.array([quat_from_euler_deg(-4 + 2 * math.sin(x), 10 * math.sin(2 * x), 1.5 * math.cos(3 * x)) for x in t])
    return CameraTrace(t, pos, q, name="walk")


def test_camera_path_is_quasars_format_at_60_hz(tmp_path: Path) -> None:
    path = tmp_path / "path.txt"
    written = pq.write_camera_path(trace_with_roll(), path)
    lines = path.read_text().splitlines()
    assert len(lines) == len(written) == 61                     # 1 s at 60 Hz, both ends
    assert not lines[0].startswith("#")                          # QUASAR's reader takes no header
    cols = np.array([[float(v) for v in ln.split()] for ln in lines])
    assert cols.shape == (61, 7)
    np.testing.assert_allclose(cols[:, 6], np.arange(61) * 1000 / 60)      # milliseconds
    assert np.abs(cols[:, 5]).max() > 0.5                                 # the roll is kept (read as QUASAR reads it)
    back = load_quasar_path(path)                                          # what our runner reads
    np.testing.assert_allclose(back.positions, written.positions)
    np.testing.assert_allclose(np.abs(np.sum(back.orientations * written.orientations, 1)), 1.0, atol=1e-9)


def test_both_tools_read_the_same_orientations(tmp_path: Path) -> None:
    path = tmp_path / "path.txt"
    pq.write_camera_path(trace_with_roll(), path)
    assert pq.path_disagreement_deg(path) < 1e-5        # our reader and glm's formula agree, roll included (acos floor)


def test_glm_euler_is_rz_ry_rx_looking_down_minus_z() -> None:
    fwd = np.array([0.0, 0.0, -1.0])
    yaw = quat_to_matrix3(pq._glm_quat(0, 90, 0)) @ fwd
    np.testing.assert_allclose(yaw, [-1, 0, 0], atol=1e-12)                # positive yaw turns left, as ours
    pitch = quat_to_matrix3(pq._glm_quat(30, 0, 0)) @ fwd
    np.testing.assert_allclose(pitch, [0, 0.5, -math.sqrt(3) / 2], atol=1e-12)
    m = quat_to_matrix3(pq._glm_quat(20, 30, 40))
    rx, ry, rz = (quat_to_matrix3(pq._glm_quat(*a)) for a in ((20, 0, 0), (0, 30, 0), (0, 0, 40)))
    np.testing.assert_allclose(m, rz @ ry @ rx, atol=1e-12)


def test_scene_json_places_the_model_as_our_loader_does(tmp_path: Path) -> None:
    import trimesh

    from splitrender.scene.loader import get_scene

    model = tmp_path / "box.glb"
    trimesh.creation.box(extents=(1.0, 2.0, 0.5)).export(model)
    scene = get_scene(str(model))
    js = pq.scene_json_for(scene, model)
    assert js["models"][0]["path"] == str(model.resolve())
    node = js["nodes"][0]
    assert node["model"] == 0 and node["scale"] == [2.0, 2.0, 2.0]        # largest extent 2 m -> 4 m
    assert node["position"] == pytest.approx([0.0, 2.0, -4.0])             # resting on y = 0, centred on (0, y, -4)
    assert "skybox" not in js and js["camera"]["fov"] == 60.0
    assert js["directionalLight"]["direction"] == list(scene.sun.direction)
    with pytest.raises(ValueError, match="uniform scale"):
        pq.scene_json(model, np.diag([1.0, 2.0, 1.0, 1.0]), None, (0.1, 0.1, 0.1))


# ------------------------------------------------------------------------------------------ command lines


def test_command_lines() -> None:
    s = pq.Setup(320, 180, 50, 20, False, 0.5, 4)
    a = dict(scene_file=Path("/w/scene.json"), path_file=Path("/w/path.txt"), out_dir=Path("/w/q/x"))
    base = ["-s", "320x180", "-S", "/w/scene.json", "-C", "/w/path.txt", "-o", "/w/q/x", "-I"]
    assert pq.quasar_command("truth", Path("/b/scene_viewer"), s, **a) == ["/b/scene_viewer", *base]
    assert pq.quasar_command("atw", Path("/b/atw"), s, **a) == ["/b/atw", *base, "-N", "50", "-J", "20"]
    views = ["-r", "320x180", "-B", "0.5", "-F", "60", "-W", "120"]
    assert pq.quasar_command("quasar", Path("/b/qr"), s, **a) == ["/b/qr", *base, "-N", "50", "-J", "20", *views, "-n", "4"]
    assert pq.quasar_command("quadstream", Path("/b/qs"), s, **a) == ["/b/qs", *base, "-N", "50", "-J", "20", *views, "-n", "8"]
    p = pq.Setup(640, 360, 20, 0, True, 1.0, 2)
    assert pq.quasar_command("quasar", Path("/b/qr"), p, **a)[10:] == [
        "-N", "20", "-J", "0", "-P", "-r", "640x360", "-B", "1", "-F", "60", "-W", "120", "-n", "2"]
    with pytest.raises(ValueError, match="unknown role"):
        pq.quasar_command("mw", Path("/b/mw"), s, **a)


def test_display_wrapper() -> None:
    argv = ["/b/qr", "-I"]
    has = {"xvfb-run": "/usr/bin/xvfb-run"}.get
    assert pq.with_display(argv, "auto", {"DISPLAY": ":0"}, has) == argv
    assert pq.with_display(argv, "auto", {}, has) == [*pq.XVFB, *argv]
    assert pq.with_display(argv, "always", {"DISPLAY": ":0"}, has) == [*pq.XVFB, *argv]
    assert pq.with_display(argv, "never", {}, lambda _: None) == argv
    with pytest.raises(pq.QuasarBuildError, match="no DISPLAY and no xvfb-run"):
        pq.with_display(argv, "auto", {}, lambda _: None)


def test_our_runs_match_quasars_flags(tmp_path: Path) -> None:
    from splitrender.methods import get_method, make_config

    assert pq.netem_string(50, 20) == "delay 50ms 20ms"
    assert pq.netem_string(25, 0) == "delay 25ms"
    assert pq.netem_string(0, 0) == "ideal"
    s = pq.Setup(320, 180, 50, 20, False, 0.5, 4)
    cfgs = {m: pq.our_config(m, s, tmp_path / "m.glb", tmp_path / "p.txt") for m in pq.METHODS}
    for c in cfgs.values():
        assert (c.width, c.height, c.server_fps, c.client_fps, c.predictor) == (320, 180, 30, 60, "none")
        assert c.network == "delay 50ms 20ms" and c.trace == str(tmp_path / "p.txt") and c.save_images_every == 1
        make_config(get_method(c.method).config, c.method_params)        # parameters our method accepts
    assert cfgs["atw"].method == "atw" and cfgs["atw"].method_params == {}
    assert cfgs["quasar"].method_params == {"variant": "quasar", "view_cell_m": 0.5, "wide_fov_deg": 120.0, "layers": 4}
    assert cfgs["quadstream"].method_params == {"variant": "quadstream", "view_cell_m": 0.5, "wide_fov_deg": 120.0}
    assert pq.our_config("atw", pq.Setup(prediction=True), tmp_path / "m.glb", tmp_path / "p.txt").predictor == "ca"
    lossless = {m: pq.our_config(m, pq.Setup(lossless=True, unlit=True), tmp_path / "m.glb", tmp_path / "p.txt")
                for m in pq.METHODS}
    for m, c in lossless.items():                     # QUASAR never encodes colour: --lossless, every method of ours
        assert c.method_params == {**cfgs[m].method_params, "lossless": True} and c.scene.endswith("m.glb+nosun")
        assert make_config(get_method(c.method).config, c.method_params).lossless


# ------------------------------------------------------------------------------------------ the build folder


def fake_build(root: Path, leave_out: str = "", executable: bool = True) -> Path:
    for name, rel in pq.QUASAR_PROGRAMS.values():
        if name == leave_out:
            continue
        p = root / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text("#!/bin/sh\n")
        p.chmod(0o755 if executable else 0o644)
    return root


def test_find_programs_in_a_build(tmp_path: Path) -> None:
    build = fake_build(tmp_path / "build")
    found = pq.find_quasar_programs(build)
    assert found == {role: (build / rel).resolve() for role, (_, rel) in pq.QUASAR_PROGRAMS.items()}
    assert pq.find_quasar_programs(build / "apps") == found             # its apps folder will do too


@pytest.mark.skipif(os.name != "posix", reason="executable bits")
def test_missing_or_unusable_programs_are_named(tmp_path: Path) -> None:
    build = fake_build(tmp_path / "build", leave_out="qs_simulator")
    with pytest.raises(pq.QuasarBuildError) as e:
        pq.find_quasar_programs(build)
    msg = str(e.value)
    assert f"lacks qs_simulator (expected at {build / 'apps/quadstream/simulator/qs_simulator'})" in msg
    assert "qr_simulator (" not in msg and "docs/quasar.md" in msg
    plain = fake_build(tmp_path / "plain", executable=False)
    with pytest.raises(pq.QuasarBuildError, match=r"scene_viewer \(.*scene_viewer is not an executable file\)"):
        pq.find_quasar_programs(plain)
    with pytest.raises(pq.QuasarBuildError, match="does not exist"):
        pq.find_quasar_programs(tmp_path / "nowhere")
    with pytest.raises(pq.QuasarBuildError, match="--quasar-build DIR is required"):
        pq.find_quasar_programs(None)


def test_main_stops_before_any_work_without_quasar(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out, work = tmp_path / "r.json", tmp_path / "work"
    common = ["--out", str(out), "--work", str(work), "--xvfb", "never"]
    assert pq.main(common) == 2
    assert "--quasar-build DIR is required" in capsys.readouterr().err
    assert pq.main(["--quasar-build", str(fake_build(tmp_path / "b", leave_out="scene_viewer")), *common]) == 2
    assert "lacks scene_viewer" in capsys.readouterr().err
    build = str(fake_build(tmp_path / "c"))
    assert pq.main(["--quasar-build", build, *common]) == 2
    assert "--model PATH is required" in capsys.readouterr().err
    (tmp_path / "m.fbx").write_text("v 0 0 0\n")
    assert pq.main(["--quasar-build", build, "--model", str(tmp_path / "m.fbx"), *common]) == 2
    assert "not a model file" in capsys.readouterr().err
    assert not out.exists() and not work.exists()


def _tetra_obj(path: Path) -> Path:
    path.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n")
    return path


def test_models_quasar_cannot_load_are_converted_to_plain_gltf(tmp_path: Path) -> None:
    """A glTF naming a missing texture (QUASAR aborts on it) or another format is converted to work/model.glb with
    the same geometry and no texture; a complete glTF file is used as it is."""
    import trimesh

    work = tmp_path / "work"
    work.mkdir()
    obj = _tetra_obj(tmp_path / "t.obj")
    out, why = pq.prepare_model(obj, work)
    assert out == work / "model.glb" and why == ".obj converted to glTF"
    back = trimesh.load(str(out), force="scene")
    assert len(back.triangles) == 4 and np.allclose(back.bounds, [[0, 0, 0], [1, 1, 1]])
    assert pq.missing_references(out) == []
    same, why = pq.prepare_model(out, work)                    # complete glTF: itself
    assert same == out and why is None
    doc = {"asset": {"version": "2.0"}, "images": [{"uri": "gone.png"}], "buffers": [{"uri": "gone.bin"}]}
    (tmp_path / "m.gltf").write_text(json.dumps(doc))
    assert pq.missing_references(tmp_path / "m.gltf") == ["gone.png", "gone.bin"]
    # a real glTF whose texture is missing: assimp's BoxTextured with its .bin but not its .png
    src = Path("/usr/share/assimp/models/glTF2/BoxTextured-glTF")
    if src.is_dir():
        box = tmp_path / "box"
        box.mkdir()
        for f in src.glob("*.gltf"):
            (box / f.name).write_text(f.read_text())
        for f in src.glob("*.bin"):
            (box / f.name).write_bytes(f.read_bytes())
        gltf = next(box.glob("*.gltf"))
        assert pq.missing_references(gltf) and all(r.endswith(".png") for r in pq.missing_references(gltf))
        out, why = pq.prepare_model(gltf, work)
        assert why is not None and "textures stripped" in why and pq.missing_references(out) == []
        assert len(trimesh.load(str(out), force="scene").triangles) == 12


# ------------------------------------------------------------------------------------------ scoring


def test_background_mask_and_repaint() -> None:
    sky = (140, 178, 230)
    img = np.tile(np.array(sky, np.uint8), (4, 6, 1))
    img[1:3, 2:4] = (90, 90, 90)
    assert pq.background_colour([img, img]) == sky
    mask = pq.model_mask(img, sky)
    assert mask.sum() == 4 and mask[1:3, 2:4].all()
    shown = img.copy()
    shown[0, 0] = (143, 178, 228)                     # codec noise over the sky: 3 code values off
    black = (0, 0, 0)
    t2, s2 = pq.repaint_background(img, sky, black), pq.repaint_background(shown, sky, black)
    assert tuple(t2[3, 5]) == black and tuple(t2[1, 2]) == (90, 90, 90)         # the model stays
    assert tuple(s2[0, 0]) == (3, 0, 0)               # moved, not snapped: its error is kept (less clipping)
    assert pq.model_mask(t2, black).sum() == 4


def test_a_simulator_s_own_background_is_moved_to_the_truth_s(tmp_path: Path) -> None:
    """QUASAR's scene_viewer shows (208, 208, 0) where nothing is (llvmpipe), its qr/qs simulators draw on black: each
    simulator's frames are scored with their own background moved to the truth's, the model untouched."""
    from PIL import Image

    setup = pq.Setup(24, 16, 50, 20, False, 0.5, 4)
    truth_bg, sim_bg = (208, 208, 0), (0, 0, 0)
    for folder, bg in (("truth", truth_bg), ("qr", sim_bg)):
        (tmp_path / folder).mkdir()
        for i in range(3):
            img = np.tile(np.array(bg, np.uint8), (16, 24, 1))
            img[3:13, 4:20] = (90, 100, 110)
            Image.fromarray(img).save(tmp_path / folder / f"frame_{i:06d}.png")
    assert pq.simulator_background(tmp_path / "qr", setup, 0) == sim_bg
    raw = list(pq.quasar_pairs(tmp_path / "qr", tmp_path / "truth", setup, 1))
    moved = list(pq.quasar_pairs(tmp_path / "qr", tmp_path / "truth", setup, 1, (sim_bg, truth_bg)))
    assert len(raw) == len(moved) == 2
    assert pq.score_pairs(raw, truth_bg)["psnr_db"] < 10.0             # every background pixel 208 off
    r = pq.score_pairs(moved, truth_bg)
    assert r["psnr_db"] == 60.0 and r["model_psnr_db"] == 60.0


def test_score_pairs_whole_frame_and_model() -> None:
    bg = (0, 0, 0)
    truth = np.zeros((20, 20, 3), np.uint8)
    truth[:10] = 200                                  # the model: the top half
    exact = pq.score_pairs([(truth, truth)], bg)
    assert exact["frames"] == 1 and exact["psnr_db"] == 60.0 and exact["model_psnr_db"] == 60.0
    assert exact["model_pct"] == 50.0
    shown = truth.copy()
    shown[0, :] = 190                                 # 20 model pixels off by 10 in every channel
    r = pq.score_pairs([(shown, truth), (truth, truth)], bg)
    assert r["frames"] == 2
    assert r["psnr_db"] == pytest.approx((10 * math.log10(255**2 / 5.0) + 60.0) / 2)        # MSE 100 * 20 / 400
    assert r["model_psnr_db"] == pytest.approx((10 * math.log10(255**2 / 10.0) + 60.0) / 2)  # over the 200 model pixels
    assert r["psnr_mse_db"] == pytest.approx(10 * math.log10(255**2 / 2.5))


def test_coverage_counts_missed_model_pixels_and_bleed_exactly() -> None:
    """Missed: the truth's model pixels drawn as background; bleed: the truth's background pixels drawn over.  Both
    pooled over frames, as counts per frame and as a share of the truth's model pixels; a colour error inside the
    model is neither, and a pixel within the tolerance of the background counts as background."""
    bg = (208, 208, 0)
    truth = np.zeros((20, 20, 3), np.uint8)
    truth[:] = bg
    truth[5:15, 5:15] = (90, 90, 90)                  # the model: 100 pixels
    shown = truth.copy()
    shown[5, 5:15] = bg                               # 10 model pixels missed
    shown[6, 5:15] = (bg[0] - 6, bg[1] + 6, 6)        # 10 more, within the tolerance (6) of the background
    shown[7, 5:15] = (120, 60, 90)                    # 10 model pixels in the wrong colour: neither
    shown[15:17, 5:15] = (90, 90, 90)                 # 20 background pixels bled over
    shown[0, 0] = (bg[0] - 7, bg[1], bg[2])           # 1 more, just past the tolerance
    r = pq.score_pairs([(shown, truth), (truth, truth)], bg)
    assert r["model_px_per_frame"] == 100.0
    assert r["missed_px_per_frame"] == 10.0 and r["missed_pct"] == 10.0           # 20 of 200 model pixels
    assert r["bleed_px_per_frame"] == 10.5 and r["bleed_pct"] == 10.5             # 21 over 200 model pixels
    exact = pq.score_pairs([(truth, truth)], bg)
    assert exact["missed_pct"] == 0.0 and exact["bleed_pct"] == 0.0
    empty = np.zeros_like(truth)
    empty[:] = bg
    none = pq.score_pairs([(truth, empty)], bg)                                   # no model in the truth
    assert math.isnan(none["missed_pct"]) and math.isnan(none["bleed_pct"]) and none["bleed_px_per_frame"] == 100.0
    cov = pq.Coverage()
    cov.add(shown, pq.model_mask(truth, bg), bg)
    assert (cov.frames, cov.model_px, cov.missed_px, cov.bleed_px) == (1, 100, 20, 21)
    line = pq.format_table([{"tool": "QUASAR", "method": "quadstream", **r}]).splitlines()[1].split()
    assert line[-2:] == ["10.00", "10.50"]


def test_gains_over_each_tools_own_atw_and_table() -> None:
    rows = [{"tool": "QUASAR", "method": "atw", "psnr_db": 25.0, "model_psnr_db": 20.0, "frames": 3},
            {"tool": "QUASAR", "method": "quasar", "psnr_db": 31.5, "model_psnr_db": float("nan"), "frames": 3},
            {"tool": "splitrender", "method": "quadstream", "psnr_db": 33.0, "model_psnr_db": 30.0, "frames": 3,
             "bytes_ours": 1234.4, "bytes_quasar": None}]
    pq.add_gains(rows)
    assert rows[0]["gain_db"] == 0.0 and rows[1]["gain_db"] == 6.5
    assert rows[1]["model_gain_db"] is None                               # NaN model score: no gain
    assert rows[2]["gain_db"] is None                                     # no splitrender atw row
    text = pq.format_table(rows).splitlines()
    assert len(text) == 4 and "PSNR" in text[0] and "+6.50" in text[2] and "1234" in text[3]
    assert text[3].split()[-6:] == ["-"] * 6        # QUASAR-way bytes, proxies, missed and bleed: not counted


def test_truth_content_tells_an_unlit_model_from_a_lit_one() -> None:
    """Five flat colours (QUASAR's llvmpipe truth) against a shaded gradient (ours, lit): the colour count and the
    contrast inside the model tell them apart; the background is left out."""
    bg = (208, 208, 0)
    flat = np.zeros((40, 60, 3), np.uint8) + np.array(bg, np.uint8)
    flat[10:30, 10:50] = (105, 110, 119)
    flat[10:30, 30:50] = (0, 92, 119)
    lit = flat.copy()
    ramp = np.linspace(40, 200, 40).astype(np.uint8)
    lit[10:30, 10:50] = np.stack([ramp, ramp, ramp], -1)[None, :, :]
    f, l = pq.truth_content([flat, flat], bg), pq.truth_content([lit], bg)
    assert f == {"frames": 2, "model_colours": 2.0, "model_contrast": pytest.approx(105 * 20 / (20 * 39))}
    assert l["frames"] == 1 and l["model_colours"] == 40 and 3.5 < l["model_contrast"] < 4.5
    assert pq.truth_content([flat * 0 + np.array(bg, np.uint8)], bg)["frames"] == 0


def test_quasar_rows_run_ours_alone_against_an_earlier_run_of_the_same_walk(tmp_path: Path) -> None:
    """``--quasar-rows``: no QUASAR build or display needed; the earlier run's walk and QUASAR-side set-up must be
    this run's (each difference named), what only ours changes (unlit, lossless) may differ."""
    model = tmp_path / "m.glb"
    model.write_bytes(b"glTF")
    earlier = tmp_path / "earlier.json"
    setup = pq.Setup(unlit=True, lossless=True)
    old = {"trace": "strafe", "duration_s": 5.0, "path_samples": 301, "skip_s": 0.5,
           "setup": {**{k: getattr(setup, k) for k in pq.SAME_SETUP_KEYS}, "unlit": False},
           "rows": [{"tool": "QUASAR", "method": "quadstream", "missed_pct": 0.08}]}
    earlier.write_text(json.dumps(old))
    args = pq.parse_args(["--model", str(model), "--quasar-rows", str(earlier), "--unlit", "--lossless", "--xvfb", "never"])
    programs, _, got = pq.check_inputs(args)
    assert programs == {} and got == setup
    assert pq.stored_quasar_run(args, got, 301)["rows"][0]["missed_pct"] == 0.08
    with pytest.raises(pq.InputError, match="path_samples 301 there, 121 here"):
        pq.stored_quasar_run(args, got, 121)
    with pytest.raises(pq.InputError, match="setup view_cell_m 0.5 there, 1.0 here"):
        pq.stored_quasar_run(pq.parse_args(["--model", str(model), "--quasar-rows", str(earlier), "--view-cell", "1"]),
                             pq.Setup(view_cell_m=1.0), 301)
    earlier.write_text(json.dumps({**old, "rows": []}))
    with pytest.raises(pq.InputError, match="no QUASAR rows"):
        pq.stored_quasar_run(args, got, 301)
    with pytest.raises(pq.InputError, match="no such file"):
        pq.check_inputs(pq.parse_args(["--model", str(model), "--quasar-rows", str(tmp_path / "none.json")]))
