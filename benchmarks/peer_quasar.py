"""QUASAR's own simulators beside ours on one model and one camera path (issue 38, item 1).

Given a build of QUASAR (quasar-gfx/QUASAR, C++; ``docs/quasar.md`` has the recipe), this runs on the same glTF model
and the same camera path (written once, read by both tools):

* QUASAR: ``scene_viewer`` (its ground truth), ``atw_simulator``, ``qr_simulator`` (QUASAR) and ``qs_simulator``
  (QuadStream), each with ``-I`` (``--save-images``) so every client frame is a PNG, and its log captured;
* ours, in virtual time: ``atw`` and ``quads`` with ``variant`` ``quasar`` and ``quadstream``, every displayed frame
  and its ground truth kept (``save_images_every=1``).

Both tools' frames are scored by the same code (:func:`splitrender.metrics.score_frame`, then
:func:`~splitrender.metrics.quality_summary`), each against its own tool's ground truth, over the whole frame and
over the model's pixels (the pixels where that ground truth differs from its background colour by more than
:data:`~splitrender.metrics.BACKGROUND_TOLERANCE`; the background colour is the most common colour of the ground
truth's frames).  Before scoring, our frames' background and that of QUASAR's
``qr_simulator`` and ``qs_simulator`` (which draw their quad mesh on black) are moved to the colour of QUASAR's
ground truth (``--no-repaint`` leaves them): QUASAR's scene has no skybox, so ``scene_viewer``'s empty background is
whatever its lighting pass makes of the cleared G-buffer ((208, 208, 0) on llvmpipe), and the error of a stale
pixel over the background depends on that colour.  The first ``--skip`` seconds (start-up, before
our client has its first update) are not scored.

Bytes per server frame are tabulated both ways: ours (every stream on the wire: ``bytes`` in ``updates.csv``) and as
QUASAR's simulators count them (geometry only: the log's ``Frame Size``; for our ``quads`` the same count made by
:mod:`splitrender.methods.quads.accounting`, ``srv_quasar_bytes``).  QUASAR's frames cannot be counted our way (their
colour is never encoded), and ``atw_simulator`` counts nothing, so those cells are empty.

Writes ``benchmarks/results/peer_quasar.json`` and ``peer_quasar.csv``; the work files (scene JSON, camera path,
QUASAR's frames and logs, our runs' CSVs) go under ``--work`` (default ``out/peer_quasar``).

    python benchmarks/peer_quasar.py --quasar-build ~/QUASAR/build --model model.glb \\
        [--trace strafe] [--duration 5] [--size 320x180] [--latency 50] [--jitter 20] [--view-cell 0.5]

QUASAR is not built on the machines this project's CI uses: without ``--quasar-build``, or with a folder that lacks
one of the four programs, the script stops before any work and names what is missing.  Everything that needs no
QUASAR (the log parser, the camera path, the scene file, the command lines, the byte table, the scoring) is tested
in ``tests/test_peer_quasar.py``.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import re
import shutil
import subprocess
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Mapping, Sequence

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's package, not an installed one

from splitrender import metrics  # noqa: E402
from splitrender.scene.pose import quat_angle_rad  # noqa: E402
from splitrender.scene.trace import CameraTrace, load_quasar_path, save_quasar_path  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
DEFAULT_WORK = ROOT / "out" / "peer_quasar"

MB = 1024 * 1024
"""QUASAR's ``BYTES_IN_MB``: its ``Frame Size: X.XXXMB`` is bytes / 2**20."""
LOG_STEP_BYTES = MB / 1000
"""The log prints three decimals of MB: each frame's size is known to +-half of this (524 bytes)."""

QUASAR_PROGRAMS: dict[str, tuple[str, str]] = {
    "truth": ("scene_viewer", "apps/scene_viewer/scene_viewer"),
    "atw": ("atw_simulator", "apps/atw/simulator/atw_simulator"),
    "quasar": ("qr_simulator", "apps/quasar/simulator/qr_simulator"),
    "quadstream": ("qs_simulator", "apps/quadstream/simulator/qs_simulator"),
}
"""Role -> (program, its place in a CMake build folder of QUASAR)."""
METHODS = ("atw", "quasar", "quadstream")
COVER_SKY_EDGE_PX = 0.25
"""``--cover``'s reach of QuadStream's centre view past its outline against the sky (pixels; issue 50)."""
OURS: dict[str, tuple[str, dict[str, Any]]] = {
    "atw": ("atw", {}),
    "quasar": ("quads", {"variant": "quasar"}),
    "quadstream": ("quads", {"variant": "quadstream"}),
}
"""Method -> our method and its parameters (the view cell, layers and wide view are added from the set-up)."""
QS_ADDITIONAL_VIEWS = 8
"""``qs_simulator -n``: views besides the centre and the wide one (its default; 10 in all, as our QuadStream)."""
QUASAR_SERVER_FPS = 30
"""With a camera path QUASAR's simulators render server frames at 30 fps (not a flag), so ours does too."""
PATH_RATE_HZ = 60
"""The camera path's rate: QUASAR records one client frame per line, our client displays at this rate."""
XVFB = ["xvfb-run", "-a", "-s", "-screen 0 1920x1080x24"]

NO_BUILD = ("--quasar-build DIR is required: the CMake build folder of QUASAR (github.com/quasar-gfx/QUASAR), "
            "holding " + ", ".join(rel for _, rel in QUASAR_PROGRAMS.values()) + ".  QUASAR is not built here and CI "
            "never builds it; docs/quasar.md has the build recipe.")


class InputError(RuntimeError):
    """Something the benchmark needs before it starts is missing or wrong; the message names what."""


class QuasarBuildError(InputError):
    """The QUASAR build (or the display it needs) is missing or incomplete."""


@dataclass(frozen=True)
class Setup:
    """What both tools are given.  Sizes in pixels, times in ms, lengths in metres, angles in degrees."""

    width: int = 320
    height: int = 180
    latency_ms: float = 50.0
    jitter_ms: float = 20.0
    prediction: bool = False
    view_cell_m: float = 0.5
    layers: int = 4
    fov_deg: float = 60.0
    wide_fov_deg: float = 120.0
    seed: int = 0
    unlit: bool = False
    """Ours without the sun (``MODEL+nosun``): QUASAR's llvmpipe build shows the model unlit (see
    :func:`truth_content`), so only then do both ground truths show the same image."""
    lossless: bool = False
    """Our colour streams lossless (``lossless=true``): QUASAR's simulators never encode colour, so only then do
    both tools' frames carry no codec error.  With our lossy default, codec noise around the silhouette counts as
    bleed (background pixels more than the tolerance off it): on Wuson, 78 % of our QUASAR's bleed lay within 40
    code values of the sky."""
    hidden_sky_px: int = 0
    """Our QUASAR client's sky quads behind the model's silhouette (``quads`` ``hidden_sky_px``; 0: none, the
    default)."""
    cover: bool = False
    """Our quads seal the cracks between their quads (``seal_cracks``) and QuadStream's centre view covers the
    outline against the sky a quarter pixel further (``sky_edge_px`` :data:`COVER_SKY_EDGE_PX`); off: the defaults."""

    @property
    def size(self) -> str:
        return f"{self.width}x{self.height}"


# ---------------------------------------------------------------------------------------------- the QUASAR build


def _executable(p: Path) -> bool:
    return p.is_file() and os.access(p, os.X_OK)


def _search(build: Path, name: str, max_depth: int = 6) -> Path | None:
    """An executable file called ``name`` under ``build`` (CMake's own folders skipped), or None."""
    base = len(build.parts)
    for d, dirs, files in os.walk(build):
        depth = len(Path(d).parts) - base
        dirs[:] = [x for x in dirs if x != "CMakeFiles" and not x.startswith(".") and depth < max_depth]
        if name in files and _executable(Path(d) / name):
            return Path(d) / name
    return None


def find_quasar_programs(build: str | os.PathLike[str] | None) -> dict[str, Path]:
    """Role -> path of each of QUASAR's programs in the build folder ``build`` (the CMake build folder, or its
    ``apps`` folder).  Raises :class:`QuasarBuildError` naming every program that is missing or not executable."""
    if build is None or str(build) == "":
        raise QuasarBuildError(NO_BUILD)
    root = Path(build).expanduser()
    if not root.is_dir():
        raise QuasarBuildError(f"QUASAR build folder {root} does not exist or is not a folder.  {NO_BUILD}")
    found: dict[str, Path] = {}
    problems: list[str] = []
    for role, (name, rel) in QUASAR_PROGRAMS.items():
        candidates = [root / rel, root / rel.removeprefix("apps/"), root / name]
        hit = next((c for c in candidates if _executable(c)), None) or _search(root, name)
        if hit is not None:
            found[role] = hit.resolve()
            continue
        present = next((c for c in candidates if c.exists()), None)
        if present is not None:
            problems.append(f"{name} ({present} is not an executable file)")
        else:
            problems.append(f"{name} (expected at {root / rel})")
    if problems:
        raise QuasarBuildError(f"QUASAR build folder {root} lacks {'; '.join(problems)}.  peer_quasar runs "
                               f"{', '.join(n for n, _ in QUASAR_PROGRAMS.values())}: build QUASAR with its apps "
                               "(docs/quasar.md) and pass the CMake build folder.")
    return found


def with_display(argv: list[str], mode: str = "auto", env: Mapping[str, str] | None = None,
                 which: Callable[[str], str | None] = shutil.which) -> list[str]:
    """``argv`` run under ``xvfb-run`` when ``mode`` is ``always``, or ``auto`` with no ``DISPLAY`` (QUASAR's programs
    open a GLFW window, hidden with ``--save-images`` but still on an X display); ``never`` leaves it."""
    if mode not in ("auto", "always", "never"):
        raise ValueError(f"display mode {mode!r} is not one of auto, always, never")
    env = os.environ if env is None else env
    if mode == "never" or (mode == "auto" and env.get("DISPLAY")):
        return list(argv)
    if which("xvfb-run") is None:
        raise QuasarBuildError("QUASAR's programs need an X display: there is no DISPLAY and no xvfb-run on PATH "
                               "(install xvfb, e.g. apt-get install xvfb, or run inside an X session)")
    return [*XVFB, *argv]


# ---------------------------------------------------------------------------------------------- shared inputs


def write_camera_path(trace: CameraTrace, path: Path, rate_hz: float = PATH_RATE_HZ) -> CameraTrace:
    """Write the camera path both tools read: ``trace`` sampled at ``rate_hz`` (QUASAR records a client frame per
    line), as QUASAR's 7 columns with no header (glm's Euler angles, which our reader reads as QUASAR does).
    Returns the trace written."""
    t = trace.sample(rate_hz)
    save_quasar_path(t, path, header=False)
    return t


def _glm_quat(rx: float, ry: float, rz: float) -> np.ndarray:
    """glm's ``quat(vec3 eulerAngles)`` written out component by component (radians from degrees), as our (x, y,
    z, w): an independent reading of a path line to hold our reader against."""
    cx, cy, cz = (math.cos(math.radians(a) / 2) for a in (rx, ry, rz))
    sx, sy, sz = (math.sin(math.radians(a) / 2) for a in (rx, ry, rz))
    return np.array([sx * cy * cz - cx * sy * sz, cx * sy * cz + sx * cy * sz, cx * cy * sz - sx * sy * cz,
                     cx * cy * cz + sx * sy * sz])


def path_disagreement_deg(path: Path) -> float:
    """The largest angle (degrees) between our reading of a path file's orientations and QUASAR's reading of the
    same numbers (0 up to rounding when the conventions agree on it)."""
    ours = load_quasar_path(path)
    rows = [line.split() for line in path.read_text().splitlines() if line.strip()]
    worst = 0.0
    for q, r in zip(ours.orientations, rows):
        theirs = _glm_quat(float(r[3]), float(r[4]), float(r[5]))
        worst = max(worst, math.degrees(quat_angle_rad(q, theirs)))
    return worst


def netem_string(latency_ms: float, jitter_ms: float) -> str:
    """Our network for QUASAR's ``-N latency -J jitter``: QUASAR delays the pose by latency +- jitter (uniform) on its
    way to the server and again on the frame's way back, so both directions get ``delay L J`` (netem's jitter is
    uniform without a distribution table)."""
    if latency_ms < 0 or jitter_ms < 0:
        raise ValueError(f"latency and jitter must be >= 0, got {latency_ms} and {jitter_ms}")
    if latency_ms == 0 and jitter_ms == 0:
        return "ideal"
    if jitter_ms == 0:
        return f"delay {latency_ms:g}ms"
    return f"delay {latency_ms:g}ms {jitter_ms:g}ms"


def scene_json(model: Path, transform: np.ndarray, sun: tuple[Sequence[float], Sequence[float], float] | None,
               ambient: Sequence[float], fov_deg: float = 60.0,
               point_lights: Sequence[tuple[Sequence[float], Sequence[float], float]] = ()) -> dict[str, Any]:
    """QUASAR's scene file (``-S``; ``renderer/src/SceneLoader.cpp``) for the glTF ``model`` placed by ``transform``
    (our loader's: a uniform scale and a translation; QUASAR's node is T * R * S).  ``sun``: (direction, colour,
    intensity) of a directional light; ``ambient``: its colour at intensity 1; ``point_lights``: (position, colour,
    intensity) each, with QUASAR's default attenuation.  No skybox: the background is QUASAR's lit clear colour.
    The lights are mirrored, not matched (the two renderers' units differ); each tool is scored against its own
    renderer."""
    t = np.asarray(transform, dtype=np.float64)
    s = float(t[0, 0])
    if t.shape != (4, 4) or not np.allclose(t[:3, :3], s * np.eye(3), atol=1e-9 * max(1.0, abs(s))) or s <= 0:
        raise ValueError("the model's transform must be a positive uniform scale and a translation")
    out: dict[str, Any] = {
        "models": [{"name": model.stem, "path": str(model.resolve()), "IBL": 0.0, "flipTextures": True,
                    "gammaCorrected": True}],
        "nodes": [{"model": 0, "position": [float(v) for v in t[:3, 3]], "rotation": [0.0, 0.0, 0.0],
                   "scale": [s, s, s]}],
        "camera": {"fov": float(fov_deg), "near": 0.1, "far": 1000.0},
        "ambientLight": {"color": [float(c) for c in ambient], "intensity": 1.0},
    }
    if sun is not None:
        d, col, inten = sun
        out["directionalLight"] = {"color": [float(c) for c in col], "direction": [float(v) for v in d],
                                   "distance": 10.0, "intensity": float(inten), "orthoBoxSize": 20.0}
    if point_lights:
        out["pointLights"] = [{"color": [float(c) for c in col], "position": [float(v) for v in pos],
                               "intensity": float(inten)} for pos, col, inten in point_lights]
    return out


def scene_json_for(scene: Any, model: Path, fov_deg: float = 60.0) -> dict[str, Any]:
    """:func:`scene_json` for a scene our loader made of ``model`` (every object carries the same transform)."""
    transforms = [o.transform for o in scene.objects if not getattr(o, "backdrop", False)]
    if not transforms or any(not np.allclose(x, transforms[0]) for x in transforms):
        raise ValueError(f"scene {scene.name}: its objects are not placed by one transform")
    sun = None
    if scene.sun is not None:
        sun = (scene.sun.direction, scene.sun.color, scene.sun.intensity.value(0.0))
    points = [(p.position, p.color, p.intensity.value(0.0)) for p in scene.point_lights]
    return scene_json(model, transforms[0], sun, scene.ambient, fov_deg, points)


MODEL_SUFFIXES = (".glb", ".gltf", ".obj", ".ply", ".dae", ".stl", ".off")
"""What ``--model`` takes: glTF as it is; the other formats our loader reads are converted (:func:`prepare_model`)."""
PLAIN_BASE_COLOUR = (204, 204, 204, 255)
"""The base colour of a converted model's materials where the file gives none (QUASAR's and our default differ)."""


def missing_references(model: Path) -> list[str]:
    """The external files a glTF file names (images, and a ``.gltf``'s buffers) that are not there.  QUASAR aborts
    on such a file ("Failed to load image"), where our loader falls back to the base colour."""
    from urllib.parse import unquote

    from splitrender.scene.loader import _texture_refs

    refs = list(_texture_refs(model))
    if model.suffix.lower() == ".gltf":
        try:
            doc = json.loads(model.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            doc = {}
        for b in doc.get("buffers", []) or []:
            uri = b.get("uri") if isinstance(b, dict) else None
            if isinstance(uri, str) and not uri.startswith("data:"):
                refs.append(uri)
    return [r for r in refs if not (model.parent / unquote(r)).exists()]


def prepare_model(model: Path, work: Path) -> tuple[Path, str | None]:
    """The glTF file both tools load, and why it was converted (None: ``model`` itself).  A glTF file whose
    references are all there is used as it is.  Any other model (another format our loader reads, or a glTF file
    naming a missing texture or buffer) is converted with trimesh to ``work/model.glb``: the same meshes and node
    transforms, vertex normals, and each material reduced to its base colour (textures dropped), so that QUASAR can
    load it."""
    import trimesh

    suffix = model.suffix.lower()
    if suffix in (".glb", ".gltf"):
        missing = missing_references(model)
        if not missing:
            return model, None
        why = "missing " + ", ".join(missing) + ": textures stripped"
    else:
        why = f"{suffix} converted to glTF"
    loaded = trimesh.load(str(model), force="scene")
    for name, g in list(loaded.geometry.items()):
        colour = PLAIN_BASE_COLOUR
        mat = getattr(getattr(g, "visual", None), "material", None)
        if mat is not None:
            base = getattr(mat, "baseColorFactor", None)
            if base is None and hasattr(mat, "main_color"):
                base = mat.main_color
            if base is not None and len(base) >= 3:
                b = np.asarray(base, dtype=np.float64)
                b = b * 255.0 if b.max() <= 1.0 else b
                colour = tuple(int(round(v)) for v in (*b[:3], 255))
        g.visual = trimesh.visual.TextureVisuals(material=trimesh.visual.material.PBRMaterial(
            baseColorFactor=colour, metallicFactor=0.0, roughnessFactor=1.0))
    out = work / "model.glb"
    out.write_bytes(trimesh.exchange.gltf.export_glb(loaded, include_normals=True))
    if missing_references(out):
        raise InputError(f"{out}: the converted model still names missing files")
    return out, why


def quasar_command(role: str, program: Path, setup: Setup, scene_file: Path, path_file: Path, out_dir: Path) -> list[str]:
    """The command line of QUASAR's program for ``role`` (``truth``, ``atw``, ``quasar``, ``quadstream``)."""
    if role not in QUASAR_PROGRAMS:
        raise ValueError(f"unknown role {role!r}; valid: {', '.join(QUASAR_PROGRAMS)}")
    argv = [str(program), "-s", setup.size, "-S", str(scene_file), "-C", str(path_file), "-o", str(out_dir), "-I"]
    if role == "truth":
        return argv
    argv += ["-N", f"{setup.latency_ms:g}", "-J", f"{setup.jitter_ms:g}"]
    if setup.prediction:
        argv.append("-P")
    if role == "atw":
        return argv
    argv += ["-r", setup.size, "-B", f"{setup.view_cell_m:g}", "-F", f"{setup.fov_deg:g}", "-W", f"{setup.wide_fov_deg:g}",
             "-n", str(setup.layers if role == "quasar" else QS_ADDITIONAL_VIEWS)]
    return argv


def our_config(method: str, setup: Setup, model: Path, path_file: Path) -> Any:
    """Our run of ``method`` (``atw``, ``quasar``, ``quadstream``) on the same model, path and network."""
    from splitrender.sim.config import RunConfig

    name, params = OURS[method]
    params = dict(params)
    if setup.lossless:
        params["lossless"] = True
    if name == "quads":
        params.update(view_cell_m=setup.view_cell_m, wide_fov_deg=setup.wide_fov_deg)
        if params["variant"] == "quasar":
            params["layers"] = setup.layers
            if setup.hidden_sky_px:
                params["hidden_sky_px"] = setup.hidden_sky_px
        if setup.cover:
            params["seal_cracks"] = True
            if params["variant"] == "quadstream":
                params["sky_edge_px"] = COVER_SKY_EDGE_PX
    return RunConfig(method=name, method_params=params, scene=str(model) + ("+nosun" if setup.unlit else ""),
                     trace=str(path_file),
                     network=netem_string(setup.latency_ms, setup.jitter_ms), width=setup.width, height=setup.height,
                     fov_y_deg=setup.fov_deg, server_fps=QUASAR_SERVER_FPS, client_fps=PATH_RATE_HZ,
                     predictor="ca" if setup.prediction else "none", seed=setup.seed, flip_every=0,
                     save_images_every=1)


# ---------------------------------------------------------------------------------------------- QUASAR's log

_ANSI = re.compile(r"\x1b\[[0-9;]*[A-Za-z]")
_PREFIX = re.compile(r"^\s*(?:\[[^\]]*\]\s*)+")
_RENDER = re.compile(r"^Rendering Time(?: \((RefFrame|ResFrame)\))?:\s*[\d.]+\s*ms")
_SIZE = re.compile(r"^Frame Size:\s*([\d.]+)\s*MB")
_PROXIES = re.compile(r"^Num Proxies:\s*(\d+)\s*Proxies")
_CLIENT = re.compile(r"^Client Render Time:")
_ERR = re.compile(r"^(Pos|Rot|RTT) \(\s*(-?[\d.]+)\s*\u00b1\s*(-?[\d.]+)")
KINDS = {"RefFrame": "reference", "ResFrame": "residual"}


@dataclass
class QuasarLog:
    """What a simulator's stdout says.  ``frames``: one dict per server frame, ``kind`` (``reference``,
    ``residual``, or None where the log does not say: QuadStream, ATW), ``bytes`` (``Frame Size`` times 2**20, None
    where not printed: ATW) and ``proxies`` (``Num Proxies``).  ``client_frames``: client frames rendered.  The pose
    error summary printed at the end: ``pos_err_m``, ``rot_err_deg``, ``rtt_ms`` (means)."""

    frames: list[dict[str, Any]] = field(default_factory=list)
    client_frames: int = 0
    pos_err_m: float | None = None
    rot_err_deg: float | None = None
    rtt_ms: float | None = None


def clean_line(line: str) -> str:
    """A log line without colour codes and spdlog's ``[12:00:00] [I]`` prefixes."""
    return _PREFIX.sub("", _ANSI.sub("", line)).strip()


def parse_quasar_log(text: str) -> QuasarLog:
    """Parse the stdout of ``qr_simulator``, ``qs_simulator`` or ``atw_simulator`` (a block per server frame, opened
    by a line of ``=``)."""
    log = QuasarLog()
    cur: dict[str, Any] | None = None

    def frame() -> dict[str, Any]:
        nonlocal cur
        if cur is None:
            cur = {"kind": None, "bytes": None, "proxies": None}
            log.frames.append(cur)
        return cur

    for raw in text.splitlines():
        line = clean_line(raw)
        if not line:
            continue
        if set(line) == {"="}:
            cur = None
            frame()
        elif m := _RENDER.match(line):
            f = frame()
            if f["kind"] is None and m.group(1):
                f["kind"] = KINDS[m.group(1)]
        elif m := _SIZE.match(line):
            frame()["bytes"] = float(m.group(1)) * MB
        elif m := _PROXIES.match(line):
            frame()["proxies"] = int(m.group(1))
        elif _CLIENT.match(line):
            log.client_frames += 1
        elif m := _ERR.match(line):
            setattr(log, {"Pos": "pos_err_m", "Rot": "rot_err_deg", "RTT": "rtt_ms"}[m.group(1)], float(m.group(2)))
    return log


# ---------------------------------------------------------------------------------------------- bytes both ways


def _mean(values: Iterable[Any]) -> float | None:
    v = [float(x) for x in values if x is not None and not (isinstance(x, float) and math.isnan(x))]
    return float(np.mean(v)) if v else None


def quasar_bytes(log: QuasarLog) -> dict[str, Any]:
    """A QUASAR simulator's bytes per server frame as it counts them (mean over every server frame, as its own
    ``stats_parser.py`` averages), split by frame kind where the log says it; ours cannot be had (None)."""
    fr = log.frames
    return {"server_frames": len(fr), "bytes_ours": None, "bytes_quasar": _mean(f["bytes"] for f in fr),
            "bytes_quasar_reference": _mean(f["bytes"] for f in fr if f["kind"] == "reference"),
            "bytes_quasar_residual": _mean(f["bytes"] for f in fr if f["kind"] == "residual"),
            "proxies": _mean(f["proxies"] for f in fr),
            "proxies_reference": _mean(f["proxies"] for f in fr if f["kind"] == "reference"),
            "proxies_residual": _mean(f["proxies"] for f in fr if f["kind"] == "residual")}


def our_bytes(updates: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """Our bytes per server frame from ``updates.csv`` rows: ours (``bytes``: every stream) and as QUASAR counts
    (``srv_quasar_bytes``, ``quads`` only; None for methods without it), split by reference/residual frame where the
    method says (``srv_reference``, QUASAR's variant)."""
    ups = list(updates)
    counted = [u for u in ups if "srv_quasar_bytes" in u]
    split = [u for u in counted if "srv_reference" in u]
    variant_residual = any(float(u["srv_reference"]) == 0.0 for u in split)
    return {"server_frames": len(ups), "bytes_ours": _mean(u["bytes"] for u in ups),
            "bytes_quasar": _mean(u["srv_quasar_bytes"] for u in counted),
            "bytes_quasar_reference": (_mean(u["srv_quasar_bytes"] for u in split if float(u["srv_reference"]) == 1.0)
                                       if variant_residual else None),
            "bytes_quasar_residual": (_mean(u["srv_quasar_bytes"] for u in split if float(u["srv_reference"]) == 0.0)
                                      if variant_residual else None),
            "proxies": _mean(u.get("srv_quasar_proxies") for u in counted),
            "proxies_reference": (_mean(u.get("srv_quasar_proxies") for u in split if float(u["srv_reference"]) == 1.0)
                                  if variant_residual else None),
            "proxies_residual": (_mean(u.get("srv_quasar_proxies") for u in split if float(u["srv_reference"]) == 0.0)
                                 if variant_residual else None)}


def bytes_table(quasar_logs: Mapping[str, QuasarLog], our_updates: Mapping[str, Sequence[Mapping[str, Any]]]) -> list[dict[str, Any]]:
    """One row per tool and method (QUASAR's first, each in :data:`METHODS` order) with its bytes per server frame
    ours and as QUASAR counts, and its proxies per frame (QUASAR's ``Num Proxies``: the visible layer only for
    ``qr_simulator``, every view for ``qs_simulator``; ours counted the same way)."""
    rows = []
    for m in METHODS:
        if m in quasar_logs:
            rows.append({"tool": "QUASAR", "method": m, "program": QUASAR_PROGRAMS[m][0], **quasar_bytes(quasar_logs[m])})
    for m in METHODS:
        if m in our_updates:
            name, params = OURS[m]
            prog = name + (f" variant={params['variant']}" if "variant" in params else "")
            rows.append({"tool": "splitrender", "method": m, "program": prog, **our_bytes(our_updates[m])})
    return rows


# ---------------------------------------------------------------------------------------------- scoring


def background_colour(images: Iterable[np.ndarray]) -> tuple[int, int, int]:
    """The most common colour over ``images`` ((H, W, 3) uint8): a ground truth's flat background."""
    counts: dict[int, int] = {}
    for img in images:
        a = np.asarray(img, np.uint8)[..., :3].reshape(-1, 3).astype(np.uint32)
        keys, n = np.unique(a[:, 0] << 16 | a[:, 1] << 8 | a[:, 2], return_counts=True)
        for k, c in zip(keys.tolist(), n.tolist()):
            counts[k] = counts.get(k, 0) + c
    if not counts:
        raise ValueError("no images to find a background colour in")
    k = max(counts, key=lambda c: counts[c])
    return (k >> 16 & 255, k >> 8 & 255, k & 255)


def _off(img: np.ndarray, colour: Sequence[int]) -> np.ndarray:
    return np.abs(img[..., :3].astype(np.int16) - np.asarray(colour, np.int16)).max(axis=-1)


def model_mask(truth: np.ndarray, background: Sequence[int], tol: int = metrics.BACKGROUND_TOLERANCE) -> np.ndarray:
    """Where the ground truth shows the model: more than ``tol`` code values from the background in some channel."""
    return _off(truth, background) > tol


def truth_content(images: Iterable[np.ndarray], background: Sequence[int]) -> dict[str, float]:
    """What a ground truth shows of the model, per frame on average: its distinct colours and the mean absolute
    difference between horizontal neighbours inside it (code values).  Two tools' truths of the same model and
    path should agree; QUASAR's llvmpipe build drew 2CylinderEngine with 5 colours (ambient x albedo: its sun
    added nothing) where ours, lit, drew about 1,100, with 17x the contrast inside the model."""
    colours, contrast, n = [], [], 0
    for t in images:
        t = np.asarray(t, np.uint8)[..., :3]
        m = model_mask(t, background)
        if m.sum() < 16:
            continue
        n += 1
        c = t[m].astype(np.uint32)
        colours.append(len(np.unique(c[:, 0] << 16 | c[:, 1] << 8 | c[:, 2])))
        both = m[:, 1:] & m[:, :-1]
        d = np.abs(t[:, 1:].astype(np.int16) - t[:, :-1].astype(np.int16)).max(-1)
        contrast.append(float(d[both].mean()) if both.any() else 0.0)
    return {"frames": n, "model_colours": float(np.mean(colours)) if colours else math.nan,
            "model_contrast": float(np.mean(contrast)) if contrast else math.nan}


CONTENT_RATIO_WARN = 3.0
"""Warn when the contrast inside the model differs between the two ground truths by more than this factor (lit
ours against QUASAR's: 17x; ours unlit: 1.4x, though our ambient still shades: 221 colours a frame against 5)."""


def repaint_background(img: np.ndarray, src: Sequence[int], dst: Sequence[int], tol: int = metrics.BACKGROUND_TOLERANCE) -> np.ndarray:
    """``img`` with every pixel within ``tol`` of the background colour ``src`` moved by ``dst - src`` (clipped), so
    a background pixel's error against a repainted truth is what it was."""
    out = img[..., :3].astype(np.int16)
    near = _off(img, src) <= tol
    out[near] += np.asarray(dst, np.int16) - np.asarray(src, np.int16)
    return np.clip(out, 0, 255).astype(np.uint8)


@dataclass
class Coverage:
    """Coverage and bleed of shown frames against their truths, pooled over the frames added (issue 50, part 2).

    * **missed**: the truth's model pixels (:func:`model_mask`) that the shown frame draws as background (within
      ``tol`` of the background colour in every channel): the model the method failed to cover;
    * **bleed**: the truth's background pixels that the shown frame covers (more than ``tol`` off the background):
      stale or stretched geometry drawn over empty space.  The model PSNR never sees it (not a model pixel).

    Both are given as counts per frame and as a share of the truth's model pixels (``missed_pct``, ``bleed_pct``:
    pooled, so a frame with more model counts more).  The shown frame must already be on the truth's background
    colour (:func:`repaint_background`)."""

    frames: int = 0
    model_px: int = 0
    missed_px: int = 0
    bleed_px: int = 0

    def add(self, shown: np.ndarray, truth_model: np.ndarray, background: Sequence[int],
            tol: int = metrics.BACKGROUND_TOLERANCE) -> None:
        drawn = _off(np.asarray(shown), background) > tol
        self.frames += 1
        self.model_px += int(truth_model.sum())
        self.missed_px += int((truth_model & ~drawn).sum())
        self.bleed_px += int((~truth_model & drawn).sum())

    def summary(self) -> dict[str, Any]:
        n, m = max(self.frames, 1), self.model_px
        return {"model_px_per_frame": self.model_px / n, "missed_px_per_frame": self.missed_px / n,
                "bleed_px_per_frame": self.bleed_px / n,
                "missed_pct": 100.0 * self.missed_px / m if m else math.nan,
                "bleed_pct": 100.0 * self.bleed_px / m if m else math.nan}


def score_pairs(pairs: Iterable[tuple[np.ndarray, np.ndarray]], background: Sequence[int],
                tol: int = metrics.BACKGROUND_TOLERANCE) -> dict[str, Any]:
    """Score (shown, truth) pairs with the project's :func:`~splitrender.metrics.score_frame` (the model region
    from :func:`model_mask`) and aggregate them with :func:`~splitrender.metrics.quality_summary`: the mean of the
    per-frame PSNRs (capped at 60 dB) over the whole frame and over the model's pixels, and each PSNR of the mean
    MSE, SSIM, the model's share of the frame and the frames scored; and the model pixels missed and the background
    pixels bled over (:class:`Coverage`)."""
    rows, cov = [], Coverage()
    for s, t in pairs:
        truth_model = model_mask(t, background, tol)
        rows.append(metrics.score_frame(s, None, t, None, False, truth_model=truth_model))
        cov.add(s, truth_model, background, tol)
    q = metrics.quality_summary(rows)
    return {"frames": len(rows), "psnr_db": q["mean_psnr_db"], "model_psnr_db": q["mean_model_psnr_db"],
            "psnr_mse_db": q["psnr_mse_db"], "model_psnr_mse_db": q["model_psnr_mse_db"], "ssim": q["mean_ssim"],
            "model_ssim": q["mean_model_ssim"], "model_pct": q["mean_model_pct"], "model_frames": q["model_frames"],
            **cov.summary()}


def add_gains(rows: list[dict[str, Any]]) -> None:
    """Each row's ``gain_db`` and ``model_gain_db``: its PSNRs less those of the same tool's ``atw`` row."""
    atw = {r["tool"]: r for r in rows if r["method"] == "atw"}
    for r in rows:
        base = atw.get(r["tool"])
        for k, g in (("psnr_db", "gain_db"), ("model_psnr_db", "model_gain_db")):
            a, b = r.get(k), base.get(k) if base else None
            r[g] = a - b if a is not None and b is not None and not (math.isnan(a) or math.isnan(b)) else None


def _cell(v: Any, fmt: str) -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "-"
    return format(v, fmt)


def format_table(rows: Sequence[Mapping[str, Any]]) -> str:
    """The results as a text table (``-``: not measured or not counted)."""
    cols = [("tool", "<11", "s"), ("method", "<10", "s"), ("frames", ">6", "d"), ("PSNR", ">6", ".2f"),
            ("model", ">6", ".2f"), ("gain", ">6", "+.2f"), ("m.gain", ">6", "+.2f"), ("B/frame ours", ">12", ".0f"),
            ("B/frame QUASAR", ">14", ".0f"), ("proxies", ">8", ".0f"), ("ref", ">6", ".0f"), ("res", ">6", ".0f"),
            ("missed%", ">7", ".2f"), ("bleed%", ">7", ".2f")]
    keys = ["tool", "method", "frames", "psnr_db", "model_psnr_db", "gain_db", "model_gain_db", "bytes_ours",
            "bytes_quasar", "proxies", "proxies_reference", "proxies_residual", "missed_pct", "bleed_pct"]
    lines = ["  ".join(format(h, a) for h, a, _ in cols)]
    for r in rows:
        lines.append("  ".join(format(_cell(r.get(k), f), a) for k, (_, a, f) in zip(keys, cols)))
    return "\n".join(lines)


# ---------------------------------------------------------------------------------------------- needs the QUASAR build

_FRAME = re.compile(r"^frame_(\d+)\.png$")


def frame_files(folder: Path) -> dict[int, Path]:
    """Frame index -> ``frame_%06d.png`` in ``folder`` (QUASAR's ``Recorder``)."""
    out = {}
    for p in folder.iterdir() if folder.is_dir() else ():
        m = _FRAME.match(p.name)
        if m:
            out[int(m.group(1))] = p
    return out


def load_rgb(path: Path, setup: Setup) -> np.ndarray:
    from PIL import Image

    with Image.open(path) as im:
        a = np.asarray(im.convert("RGB"))
    if a.shape != (setup.height, setup.width, 3):
        raise RuntimeError(f"{path}: {a.shape[1]}x{a.shape[0]}, expected {setup.size}")
    return a


def run_quasar(role: str, argv: list[str], cwd: Path, out_dir: Path, timeout_s: float) -> QuasarLog:
    """Run one of QUASAR's programs in ``cwd`` (its own folder: its defaults name ``../assets``), its stdout and
    stderr into ``out_dir/log.txt``; raises with the log's tail when it fails or records no frames."""
    out_dir.mkdir(parents=True, exist_ok=True)
    for old in frame_files(out_dir).values():
        old.unlink()
    log_path = out_dir / "log.txt"
    print(f"[QUASAR {role}] {' '.join(argv)}", flush=True)
    t0 = time.perf_counter()
    with open(log_path, "w", encoding="utf-8") as f:
        try:
            rc = subprocess.run(argv, stdout=f, stderr=subprocess.STDOUT, cwd=cwd, timeout=timeout_s).returncode
        except subprocess.TimeoutExpired:
            rc = None
    text = log_path.read_text(encoding="utf-8", errors="replace")
    tail = "\n".join(text.splitlines()[-15:])
    if rc != 0:
        why = f"timed out after {timeout_s:g} s" if rc is None else f"exited with {rc}"
        raise RuntimeError(f"QUASAR {role} ({QUASAR_PROGRAMS[role][0]}) {why}; log {log_path}, its end:\n{tail}")
    if not frame_files(out_dir):
        raise RuntimeError(f"QUASAR {role} wrote no frame_*.png into {out_dir}; log {log_path}, its end:\n{tail}")
    print(f"[QUASAR {role}] {len(frame_files(out_dir))} frames in {time.perf_counter() - t0:.0f} s", flush=True)
    return parse_quasar_log(text)


def quasar_pairs(sim_dir: Path, truth_dir: Path, setup: Setup, skip: int,
                 repaint: tuple[Sequence[int], Sequence[int]] | None = None) -> Iterable[tuple[np.ndarray, np.ndarray]]:
    """(shown, truth) of every frame index both folders hold, from ``skip`` on; ``repaint`` = (src, dst): the shown
    frames' background moved from ``src`` to ``dst`` (:func:`repaint_background`)."""
    sim, truth = frame_files(sim_dir), frame_files(truth_dir)
    for i in sorted(set(sim) & set(truth)):
        if i >= skip:
            shown = load_rgb(sim[i], setup)
            yield (repaint_background(shown, *repaint) if repaint else shown), load_rgb(truth[i], setup)


def simulator_background(sim_dir: Path, setup: Setup, skip: int) -> tuple[int, int, int]:
    """The most common colour of a QUASAR program's own frames (every tenth from ``skip``).  ``scene_viewer`` and
    ``atw_simulator`` show the deferred lighting of the cleared G-buffer where nothing is (on llvmpipe (208, 208, 0):
    most likely a NaN from the lighting pass, tone-mapped), while ``qr_simulator`` and ``qs_simulator`` draw the
    received quad mesh on a black clear; each is scored with its background moved to the ground truth's."""
    frames = frame_files(sim_dir)
    return background_colour(load_rgb(frames[i], setup) for i in sorted(frames)[skip::10])


# ---------------------------------------------------------------------------------------------- needs a GL context


def run_ours(method: str, setup: Setup, model: Path, path_file: Path, renderer: Any, out_dir: Path) -> tuple[Any, list[tuple[int, np.ndarray, np.ndarray]]]:
    """Our virtual-time run of ``method``; its CSVs into ``out_dir``; returns the result and its (display index,
    shown, truth) frames."""
    from splitrender.sim.runner import run

    cfg = our_config(method, setup, model, path_file)
    t0 = time.perf_counter()
    res = run(cfg, renderer=renderer)
    images, res.images = res.images, []
    res.write(out_dir)
    print(f"[ours {method}] {len(images)} frames in {time.perf_counter() - t0:.0f} s", flush=True)
    return res, images


# ---------------------------------------------------------------------------------------------- main


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=(__doc__ or "").split("\n")[0])
    ap.add_argument("--quasar-build", help="QUASAR's CMake build folder (required; docs/quasar.md)")
    ap.add_argument("--model", help="the model both tools load (required): glTF as it is, other formats our loader "
                    "reads (and glTF naming missing textures) converted to work/model.glb")
    ap.add_argument("--trace", default="strafe", help="a built-in trace, fitted around the model (default: strafe, a "
                    "lateral walk), or a trace file")
    ap.add_argument("--duration", type=float, default=5.0, help="seconds of the trace (default 5)")
    ap.add_argument("--size", default="320x180", help="client and server size WxH (default 320x180)")
    ap.add_argument("--latency", type=float, default=50.0, help="ms each way (QUASAR -N; default 50)")
    ap.add_argument("--jitter", type=float, default=20.0, help="+- ms, uniform (QUASAR -J; default 20)")
    ap.add_argument("--prediction", action="store_true", help="pose prediction on (QUASAR -P; ours ca)")
    ap.add_argument("--view-cell", type=float, default=0.5, help="view cell size in metres (QUASAR -B; default 0.5)")
    ap.add_argument("--layers", type=int, default=4, help="QUASAR's layers, the visible one included (-n; default 4)")
    ap.add_argument("--skip", type=float, default=0.5, help="seconds at the start not scored (default 0.5)")
    ap.add_argument("--no-repaint", action="store_true", help="score every tool's frames on its own background colour "
                    "(by default ours and QUASAR's simulators' are moved to QUASAR's ground truth's)")
    ap.add_argument("--unlit", action="store_true", help="ours without the sun (MODEL+nosun), as QUASAR's llvmpipe "
                    "build draws the model (docs/quasar.md)")
    ap.add_argument("--lossless", action="store_true", help="our colour streams lossless, as QUASAR's simulators "
                    "never encode colour (codec noise around a silhouette otherwise counts as bleed)")
    ap.add_argument("--hidden-sky", type=int, default=None, help="our QUASAR client's sky quads behind the model's "
                    "silhouette, in pixels (quads hidden_sky_px; default 0: none; 8 was measured)")
    ap.add_argument("--qs-expand-edges", action="store_true", help="our QuadStream grows every silhouette by a pixel "
                    "as qs_simulator does (splitrender.methods.quads.server.QS_EXPAND_EDGES)")
    ap.add_argument("--cover", action="store_true", help="our quads with their cover of the outline and the cracks "
                    "between quads (quads seal_cracks=true; QuadStream also sky_edge_px=0.25; off by default, issue 50)")
    ap.add_argument("--ours", default=",".join(METHODS), help="which of our methods to run, comma-separated (default: "
                    "all; the others' rows are left out)")
    ap.add_argument("--reuse", action="store_true", help="take QUASAR's frames and logs already in the work folder "
                    "instead of running its programs again")
    ap.add_argument("--quasar-rows", metavar="JSON", help="run ours alone: QUASAR's rows, its truth's background "
                    "colour and content taken from an earlier run's JSON on the same model, walk and set-up (checked), "
                    "so that none of QUASAR's programs runs and no build is needed")
    ap.add_argument("--xvfb", choices=("auto", "always", "never"), default="auto",
                    help="run QUASAR under xvfb-run: auto = when there is no DISPLAY (default)")
    ap.add_argument("--timeout", type=float, default=1800.0, help="seconds each QUASAR program may run")
    ap.add_argument("--work", default=str(DEFAULT_WORK), help=f"work folder (default {DEFAULT_WORK.relative_to(ROOT)})")
    ap.add_argument("--out", default=str(RESULTS / "peer_quasar.json"), help="the JSON written (a CSV beside it)")
    return ap.parse_args(argv)


def check_inputs(args: argparse.Namespace) -> tuple[dict[str, Path], Path, Setup]:
    """Everything checkable before any work: QUASAR's programs, the display, the model, the set-up."""
    if getattr(args, "quasar_rows", None):   # ours alone: no QUASAR program runs
        if not Path(args.quasar_rows).is_file():
            raise InputError(f"--quasar-rows {args.quasar_rows}: no such file (an earlier run's JSON)")
        programs: dict[str, Path] = {}
    else:
        programs = find_quasar_programs(args.quasar_build)
        with_display([], args.xvfb)   # raises now, not after our runs, when there is no display
    if not args.model:
        raise InputError("--model PATH is required: the model (.glb/.gltf, or a format converted to it) both tools load")
    model = Path(args.model).expanduser().resolve()
    if not model.is_file() or model.suffix.lower() not in MODEL_SUFFIXES:
        raise InputError(f"--model {model}: not a model file ({', '.join(MODEL_SUFFIXES)}; glTF is used as it is, the "
                         "others are converted to glTF so that both tools load the same file)")
    try:
        w, h = (int(v) for v in args.size.lower().split("x"))
    except ValueError:
        raise InputError(f"--size {args.size!r}: expected WxH, e.g. 320x180") from None
    setup = Setup(w, h, args.latency, args.jitter, args.prediction, args.view_cell, args.layers, unlit=args.unlit,
                  lossless=args.lossless, hidden_sky_px=args.hidden_sky or 0, cover=args.cover)
    if not 1 <= setup.layers <= 4:
        raise InputError(f"--layers {setup.layers}: ours takes 1 to 4")
    return programs, model, setup


SAME_RUN_KEYS = ("trace", "duration_s", "path_samples", "skip_s")
SAME_SETUP_KEYS = ("width", "height", "latency_ms", "jitter_ms", "prediction", "view_cell_m", "layers", "fov_deg",
                   "wide_fov_deg")


def stored_quasar_run(args: argparse.Namespace, setup: Setup, path_samples: int) -> dict[str, Any]:
    """The earlier run of ``--quasar-rows``, checked against this one: the same walk (trace, duration, path lines),
    the same start-up skip and the same set-up on QUASAR's side (sizes, network, prediction, view cell, layers,
    fields of view); what only ours changes (``unlit``, ``lossless``, our parameters) may differ.  Raises
    :class:`InputError` naming the first difference."""
    old = json.loads(Path(args.quasar_rows).read_text())
    if not any(r.get("tool") == "QUASAR" for r in old.get("rows", ())):
        raise InputError(f"--quasar-rows {args.quasar_rows}: no QUASAR rows in it")
    now = {"trace": args.trace, "duration_s": args.duration, "path_samples": path_samples, "skip_s": args.skip}
    for k in SAME_RUN_KEYS:
        if old.get(k) != now[k]:
            raise InputError(f"--quasar-rows {args.quasar_rows}: {k} {old.get(k)!r} there, {now[k]!r} here")
    for k in SAME_SETUP_KEYS:
        if old.get("setup", {}).get(k) != getattr(setup, k):
            raise InputError(f"--quasar-rows {args.quasar_rows}: setup {k} {old.get('setup', {}).get(k)!r} there, "
                             f"{getattr(setup, k)!r} here")
    return old


def machine() -> dict[str, Any]:
    return {"platform": platform.platform(), "machine": platform.machine(), "cpus": os.cpu_count(),
            "load_avg": list(os.getloadavg()), "python": platform.python_version()}


def quasar_commit(build: Path) -> str | None:
    """The QUASAR checkout's commit, where the build folder lies in one."""
    try:
        r = subprocess.run(["git", "-C", str(build), "rev-parse", "HEAD"], capture_output=True, text=True, timeout=10)
    except (OSError, subprocess.TimeoutExpired):
        return None
    if r.returncode != 0:
        return None
    return r.stdout.strip() or None


def main(argv: Sequence[str] | None = None) -> int:
    args = parse_args(argv)
    try:
        programs, model, setup = check_inputs(args)
    except InputError as exc:
        print(f"peer_quasar: {exc}", file=sys.stderr)
        return 2
    from splitrender.render.renderer import Renderer
    from splitrender.scene.loader import get_scene
    from splitrender.scene.trace import get_trace
    from splitrender.tabular import write_csv

    t_start = time.perf_counter()
    work = Path(args.work).resolve()
    work.mkdir(parents=True, exist_ok=True)
    source_model = model
    model, converted = prepare_model(model, work)
    if converted:
        print(f"[model] {source_model}: {converted} -> {model}", flush=True)
    scene = get_scene(str(model))
    scene_file = work / "scene.json"
    scene_file.write_text(json.dumps(scene_json_for(scene, model, setup.fov_deg), indent=1) + "\n")
    trace = get_trace(args.trace, duration_s=args.duration, scene=scene, fov_y_deg=setup.fov_deg,
                      aspect=setup.width / setup.height)
    path_file = work / "camera_path.txt"
    written = write_camera_path(trace, path_file)
    disagreement = path_disagreement_deg(path_file)
    if disagreement > 0.01:
        raise RuntimeError(f"{path_file}: QUASAR would read orientations {disagreement:.3f} deg away from ours")
    skip = int(round(args.skip * PATH_RATE_HZ))

    # QUASAR: ground truth, then each simulator
    commands: dict[str, list[str]] = {}
    logs: dict[str, QuasarLog] = {}
    earlier = stored_quasar_run(args, setup, len(written)) if args.quasar_rows else None
    for role in ("truth", *METHODS) if earlier is None else ():
        out_dir = work / "quasar" / role
        commands[role] = with_display(quasar_command(role, programs[role], setup, scene_file, path_file, out_dir), args.xvfb)
        if args.reuse and frame_files(out_dir) and (out_dir / "log.txt").is_file():
            print(f"[QUASAR {role}] reusing {len(frame_files(out_dir))} frames and the log in {out_dir}", flush=True)
            log = parse_quasar_log((out_dir / "log.txt").read_text(encoding="utf-8", errors="replace"))
        else:
            log = run_quasar(role, commands[role], programs[role].parent, out_dir, args.timeout)
        if role != "truth":
            logs[role] = log
    truth_dir = work / "quasar" / "truth"
    if earlier is None:
        truth_frames = frame_files(truth_dir)
        q_bg = background_colour(load_rgb(truth_frames[i], setup) for i in sorted(truth_frames)[skip::10])
        content = {"quasar": truth_content((load_rgb(truth_frames[i], setup) for i in sorted(truth_frames)[skip::10]), q_bg)}
    else:
        q_bg = tuple(earlier["background"]["quasar"])
        content = {"quasar": earlier.get("truth_content", {}).get("quasar")}
        commands = earlier.get("quasar_commands") or {}

    # ours, each run scored as soon as it ends (its frames are not kept)
    from splitrender.methods.quads import server as quads_server

    if args.qs_expand_edges:
        quads_server.QS_EXPAND_EDGES = True
    renderer = Renderer()
    updates: dict[str, list[dict[str, Any]]] = {}
    scores: dict[str, dict[str, Any]] = {}
    o_bg: tuple[int, int, int] | None = None
    repaint = False
    ours = [m for m in METHODS if m in args.ours.split(",")]
    for m in ours:
        res, images = run_ours(m, setup, model, path_file, renderer, work / "ours" / m)
        if o_bg is None:     # every run has the same ground truth
            o_bg = background_colour(t for di, _, t in images[skip::10])
            repaint = not args.no_repaint and o_bg != q_bg
            content["ours"] = truth_content((t for di, _, t in images[skip::10]), o_bg)
        src, dst = o_bg, q_bg
        pairs = (((repaint_background(s, src, dst), repaint_background(t, src, dst)) if repaint else (s, t))
                 for di, s, t in images if di >= skip)
        scores[m] = {**score_pairs(pairs, dst if repaint else src), "frames_recorded": len(images),
                     "runner_mean_psnr_db": res.summary.get("mean_psnr_db"),
                     "runner_mean_model_psnr_db": res.summary.get("mean_model_psnr_db"),
                     "mean_motion_to_photon_ms": res.summary.get("mean_motion_to_photon_ms"),
                     "mean_kbps": res.summary.get("mean_kbps")}
        updates[m] = res.updates
        del images, res

    # QUASAR's scores, and the table
    rows = bytes_table(logs, updates)
    if earlier is not None:
        rows = [dict(r, quasar_run=str(args.quasar_rows)) for r in earlier["rows"] if r["tool"] == "QUASAR"] + rows
    sim_bg: dict[str, list[int]] = dict(earlier["background"].get("quasar_simulators") or {}) if earlier else {}
    for row in rows:
        m = row["method"]
        if row["tool"] == "QUASAR" and earlier is not None:
            continue
        if row["tool"] == "QUASAR":
            recorded = len(frame_files(work / "quasar" / m))
            if abs(recorded - len(written)) > 2:
                print(f"warning: QUASAR {m} recorded {recorded} frames for a path of {len(written)} lines", flush=True)
            bg = simulator_background(work / "quasar" / m, setup, skip)
            sim_bg[m] = list(bg)
            move = (bg, q_bg) if not args.no_repaint and bg != q_bg else None
            row.update(score_pairs(quasar_pairs(work / "quasar" / m, truth_dir, setup, skip, move), q_bg),
                       frames_recorded=recorded, rtt_ms=logs[m].rtt_ms, pos_err_m=logs[m].pos_err_m,
                       rot_err_deg=logs[m].rot_err_deg)
        else:
            row.update(scores[m])
    add_gains(rows)
    a = content["ours"]["model_contrast"]
    b = (content["quasar"] or {}).get("model_contrast", a)
    if max(a, b) > CONTENT_RATIO_WARN * max(1e-9, min(a, b)):
        print(f"warning: the two ground truths differ: model colours per frame {content['quasar']['model_colours']:.0f} "
              f"(QUASAR) against {content['ours']['model_colours']:.0f} (ours), contrast inside the model "
              f"{content['quasar']['model_contrast']:.1f} against {content['ours']['model_contrast']:.1f}; the model "
              "PSNRs and gains are not comparable (--unlit draws ours without the sun)", flush=True)

    out = {
        "benchmark": "peer_quasar", "model": str(model), "model_source": str(source_model), "model_converted": converted,
        "trace": args.trace, "duration_s": args.duration,
        "path_samples": len(written), "path_rate_hz": PATH_RATE_HZ, "setup": asdict(setup), "skip_s": args.skip,
        "server_fps": QUASAR_SERVER_FPS, "network_ours": netem_string(setup.latency_ms, setup.jitter_ms),
        "background": {"quasar": list(q_bg), "ours": list(o_bg or ()), "ours_repainted": repaint,
                       "quasar_simulators": sim_bg},
        "truth_content": content, "path_disagreement_deg": disagreement, "frame_size_step_bytes": LOG_STEP_BYTES,
        "quasar_build": str(Path(args.quasar_build).expanduser().resolve()) if args.quasar_build else None,
        "quasar_commit": (earlier.get("quasar_commit") if earlier is not None
                          else quasar_commit(Path(args.quasar_build).expanduser())),
        "quasar_rows_from": str(args.quasar_rows) if earlier is not None else None,
        "quasar_commands": commands, "our_configs": {m: our_config(m, setup, model, path_file).to_dict() for m in METHODS},
        "hidden_sky_px": setup.hidden_sky_px, "qs_expand_edges": quads_server.QS_EXPAND_EDGES, "splitrender_commit": quasar_commit(ROOT),
        "rows": rows, "wall_s": time.perf_counter() - t_start, "gl": renderer.ctx.info.get("GL_RENDERER"),
        "machine": machine(),
    }
    out_path = Path(args.out)
    out_path.parent.mkdir(parents=True, exist_ok=True)
    out_path.write_text(json.dumps(out, indent=1, default=str) + "\n")
    write_csv(out_path.with_suffix(".csv"), rows)
    print(format_table(rows))
    print(f"-> {out_path} and {out_path.with_suffix('.csv')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
