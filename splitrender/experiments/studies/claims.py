"""Study: the claims ledger (issue 50, part 3): the five papers' quantitative claims, each checked by runs.

Each claim is data (:data:`CLAIMS`): the paper, where it says it, its words, its number and its setting, and the
comparison rule: a measure built from named run configurations (:data:`RUNS`), a sign it should have and, where
the paper gives a number, the range that number spans.  The study runs every configuration a claim needs in every
cell (scene x camera) through the sweep executor (result store, truth cache, worker pool), computes the measure per
cell and a verdict from them:

- **holds**: the sign is right in every cell and our median lies within a factor of 2 of the paper's range;
- **holds with another magnitude**: the sign is right in every cell, the median outside that band;
- **does not hold**: the sign is wrong in at least one cell (the brief's rule: a claim that one method beats another
  counts only where it holds on several real models and on a still camera as well as a moving one); the reason says
  where it holds and where not.

A claim that fails may name diagnostic runs (``Claim.diagnostics``, full mode only), shown beside its measure in
every cell, and a cause (``Claim.cause``): words pointing at those columns, so the ledger says why with numbers it
computed.  A failing cell within a small margin of the threshold (:data:`TIE`) is called a tie in the reason; the
verdict stays "does not hold", since a tie is not a win.

Scores are the model region's (``mean_model_*_content``: the loaded model, or the objects the default scene marks,
over the frames with content), so a floor or the sky cannot stand in for the subject.  The cells: assimp's duck,
TextureTransformTest and 2CylinderEngine (Debian's assimp-testmodels; absent ones are skipped) and the default scene
without GI, each on the ``static`` trace (still) and the ``orbit`` trace (moving; fitted to a loaded model).  Claims
about latency or motion look at the moving camera only (a still camera has nothing to predict or warp) and say so.

``quick=True``: duck (or the default scene without it), the moving camera, 96x54, 0.3 s: a check of the machinery,
not evidence.  Full: every cell at 320x180, 1 s.  The full run writes ``docs/claims.md`` (:data:`DOC`) in a source
checkout; both write ``claims.md``, ``claims.csv`` (a row per claim) and ``claims_cells.csv`` (a row per claim and
cell: the measure, each run's value, its config key and its ``splitrender run`` command) into the study's folder.
The runs stay in ``<out>/studies/claims/store``, so a second invocation only runs what changed; each invocation
appends what it ran and how long to ``store/claims_history.json``, which the ledger's head quotes.  About 28 minutes
of runs on two shared cores for the full grid (188 runs).  ``probes`` runs (the DDGI claims) take the scene with its GI:
a model with ``+gi``, the default scene as it is.
"""

from __future__ import annotations

import logging
import math
import os
import shutil
import statistics
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Sequence

from ...sim.config import RunConfig
from ...sim.truth import shared_cache_setting
from ..sections import Section
from ._study import Study
from ._util import ROOT, STUDY_SCENE, run_command, store_history_text, summary_floats, update_mean
from .papers import MW60, MW120, QUASAR_T4, QUASAR_T1

log = logging.getLogger(__name__)

DOC: Path | None = ROOT / "docs" / "claims.md" if (ROOT / "docs").is_dir() else None
"""Where the full run writes the ledger (a test may set it to None)."""
RESULTS_DIR: Path | None = ROOT / "docs" / "results" / "claims" if DOC is not None else None
"""Where the full run copies the tables the ledger is built from (a row per claim, a row per claim and cell)."""

ASSIMP = "/usr/share/assimp/models"
MODELS = {"duck": f"{ASSIMP}/Collada/duck.dae",
          "TextureTransformTest": f"{ASSIMP}/glTF2/textureTransform/TextureTransformTest.gltf",
          "2CylinderEngine": f"{ASSIMP}/glTF2/2CylinderEngine-glTF-Binary/2CylinderEngine.glb"}
CAMERAS = {"still": "static", "moving": "orbit"}

RUN_MISSING = True
"""False: evaluate from the runs already in the study's store and leave the rest out (their cells read "not
measured"), to rebuild a ledger without running anything."""

#: the grid per mode (``GRID[quick]``); a test may replace entries
GRID: dict[bool, dict[str, Any]] = {
    True: {"size": (96, 54), "duration_s": 0.3, "scenes": ("duck",), "cameras": ("moving",), "workers": 2},
    False: {"size": (320, 180), "duration_s": 1.0, "scenes": ("duck", "TextureTransformTest", "2CylinderEngine",
                                                              "default"), "cameras": ("still", "moving"), "workers": 2},
}

# --- run configurations: name -> what differs from the base (server 30 Hz, client 60 Hz, ideal network) ---------
QS = {"variant": "quadstream"}
EXACT_QUADS = {"lossless": True, "delta_sim": 0.0, "coarse_passes": 0, "relaxed_coarse_passes": 0, "delta_flatten": 0.0,
               "relax": 1.0}
"""QUASAR with none of its simplifications: a quad per pixel keeping its depth offsets, a lossless atlas."""
TSS_MATCHED = {"budget_px": 3.0, "budget_max_spp": 16.0, "chroma": "444", "sliver_px": 1.0, "flip_level": 16,
               "hysteresis": 0.75, "pvs_ring": 1}
"""tss at a sample budget comparable to sas's (``benchmarks/bench_tss_matched.py``'s ``MATCHED``: 0.63-1.15x sas's
samples on the three assimp models), as the paper's table 4 compares them."""
RUNS: dict[str, dict[str, Any]] = {
    "probes": {"method": "probes", "gi": True},
    "probes 30Hz": {"method": "probes", "gi": True, "params": {"gi_hz": 30.0}},
    "probes all": {"method": "probes", "gi": True, "params": {"pvs": "all"}},
    "video ideal": {"method": "video"},
    "video cloud": {"method": "video", "network": "cloud"},
    "video 100ms": {"method": "video", "network": "delay 100ms"},
    "atw lan": {"method": "atw", "network": "lan"},
    "atw cloud": {"method": "atw", "network": "cloud"},
    "atw 100ms": {"method": "atw", "network": "delay 100ms"},
    "atw 8Hz": {"method": "atw", "server_fps": 8},
    "atw 500k": {"method": "atw", "params": {"bitrate_kbps": 500}},
    "MW60 lan": {"method": "warp", "params": MW60, "network": "lan"},
    "MW60 cloud": {"method": "warp", "params": MW60, "network": "cloud"},
    "MW60 100ms": {"method": "warp", "params": MW60, "network": "delay 100ms"},
    "MW60 8Hz": {"method": "warp", "params": MW60, "server_fps": 8},
    "MW120 cloud": {"method": "warp", "params": MW120, "network": "cloud"},
    "warp 30Hz": {"method": "warp"},
    "warp 6Hz": {"method": "warp", "server_fps": 6},
    "warp lan": {"method": "warp", "network": "lan"},
    "warp cloud": {"method": "warp", "network": "cloud"},
    "warp 2 views cloud": {"method": "warp", "params": {"views": 2}, "network": "cloud"},
    "quasar lan": {"method": "quads", "network": "lan"},
    "quasar cloud": {"method": "quads", "network": "cloud"},
    "quadstream cloud": {"method": "quads", "params": QS, "network": "cloud"},
    "sas ideal": {"method": "sas"},
    "sas 100ms": {"method": "sas", "network": "delay 100ms"},
    "sas 8Hz": {"method": "sas", "server_fps": 8},
    "sas 500k": {"method": "sas", "params": {"bitrate_kbps": 500}},
    "tss ideal": {"method": "tss"},
    "pred none lan": {"method": "video", "network": "lan", "predictor": "none", "metrics": False},
    "pred ca lan": {"method": "video", "network": "lan", "predictor": "ca", "metrics": False},
    "pred none cloud": {"method": "video", "network": "cloud", "predictor": "none", "metrics": False},
    "pred ca_savgol cloud": {"method": "video", "network": "cloud", "predictor": "ca_savgol", "metrics": False},
    # diagnostics: runs a claim shows beside its measure to say why it fails (not part of any measure)
    "MW60 lan exact depth": {"method": "warp", "params": {**MW60, "depth_coding": "lossless"}, "network": "lan"},
    "MW60 cloud exact depth": {"method": "warp", "params": {**MW60, "depth_coding": "lossless"}, "network": "cloud"},
    "quasar cloud, reference every frame": {"method": "quads", "params": {"reference_every": 1}, "network": "cloud"},
    "quasar cloud, exact quads": {"method": "quads", "params": EXACT_QUADS, "network": "cloud"},
    "quasar cloud, exact quads every frame": {"method": "quads", "params": {**EXACT_QUADS, "reference_every": 1},
                                              "network": "cloud"},
    "MW120 cloud 1:1": {"method": "warp", "params": {**MW120, "resolution_scale": 1.0}, "network": "cloud"},
    "sas lossless": {"method": "sas", "params": {"lossless": True}},
    "tss matched": {"method": "tss", "params": TSS_MATCHED},
    "tss matched lossless": {"method": "tss", "params": {**TSS_MATCHED, "lossless": True}},
    "atw cloud turn": {"method": "atw", "network": "cloud", "trace": "turn"},
    "video cloud turn": {"method": "video", "network": "cloud", "trace": "turn"},
}

#: per metric, the margin within which a failing cell reads as a tie in the verdict's reason (the verdict itself does
#: not change: a tie is not a win); a ratio's is relative (a cell within 5 % of the threshold)
TIE: dict[str, float] = {"model PSNR": 0.25, "model DSSIM": 0.001, "error pixels": 0.1, "holes": 0.1}
TIE_RATIO = 0.05

#: metric name -> (summary key, or ``updates:<column>`` for a mean over the updates; unit)
METRICS: dict[str, tuple[str, str]] = {
    "model PSNR": ("mean_model_psnr_db_content", "dB"),
    "model DSSIM": ("mean_model_dssim_content", ""),
    "kbit/s": ("steady_kbps", "kbit/s"),
    "error pixels": ("mean_lab_err_pct_content", "%"),
    "holes": ("mean_hole_geom_pct_content", "%"),  # holes where the truth shows geometry (not the frame's border)
    "pose error": ("mean_pred_err_cm", "cm"),
    "samples": ("updates:srv_samples", "samples"),
    "visibility over colour": ("ratio:kbps_vis/kbps_color", "x"),  # probes: one run's two probe streams
}


@dataclass(frozen=True)
class Claim:
    """One quantitative claim of a paper and how it is checked.

    The measure per cell is ``sum(coef * metric(run) for coef, run in terms)`` (``op="diff"``) or
    ``metric(terms[0]) / metric(terms[1])`` (``op="ratio"``); it should lie ``above`` (or ``below``) ``threshold``.
    ``paper_range`` is the paper's value of the same measure (lowest, highest over its scenes), None where it gives
    a direction only."""

    id: str
    paper: str
    where: str
    text: str
    paper_number: str
    setting: str
    metric: str
    terms: tuple[tuple[float, str], ...]
    op: str = "diff"
    expect: str = "above"
    threshold: float = 0.0
    paper_range: tuple[float, float] | None = None
    cameras: tuple[str, ...] = ("still", "moving")
    why_cameras: str = ""
    scenes: tuple[str, ...] | None = None
    """The cells' scenes this claim is checked on (None: every scene of the grid); ``why_scenes`` says why."""
    why_scenes: str = ""
    diagnostics: tuple[str, ...] = ()
    """Runs (:data:`RUNS`) shown beside the measure in every cell, outside it: what the ``cause`` points at."""
    cause: str = ""
    """Why the claim fails or differs here, as far as the runs (``diagnostics``) or a committed benchmark show it;
    printed under the verdict.  Words only: its evidence is the numbers the ledger prints."""
    evidence: Callable[[], str] | None = None
    """Builds a paragraph from a committed benchmark result that runs the paper's own protocol, where our verdict
    needs it (printed under the claim; empty when the result is absent)."""

    def runs(self) -> list[str]:
        return [r for _, r in self.terms]

    def all_runs(self) -> list[str]:
        """The measure's runs and then the diagnostics."""
        return self.runs() + [r for r in self.diagnostics if r not in self.runs()]


def _t4(a: str, b: str, net: str) -> tuple[float, float]:
    """The paper's table-4 PSNR difference ``a - b`` under ``net`` (lowest, highest over its four scenes)."""
    d = [x[0] - y[0] for x, y in zip(_T4[(a, net)], _T4[(b, net)])]
    return min(d), max(d)


def _t4_drop(a: str, b: str) -> tuple[float, float]:
    """How much more ``b`` loses than ``a`` from lan to cloud in table 4 (lowest, highest)."""
    d = [(bl[0] - bc[0]) - (al[0] - ac[0]) for al, ac, bl, bc in
         zip(_T4[(a, "lan")], _T4[(a, "cloud")], _T4[(b, "lan")], _T4[(b, "cloud")])]
    return min(d), max(d)


def _t4_loss(a: str) -> tuple[float, float]:
    """How much ``a`` loses from lan to cloud in table 4 (lowest, highest over its four scenes)."""
    d = [x[0] - y[0] for x, y in zip(_T4[(a, "lan")], _T4[(a, "cloud")])]
    return min(d), max(d)


def _num(r: tuple[float, float], unit: str, fmt: str = "+.2f") -> str:
    """The paper's number, written from its range."""
    return f"{r[0]:{fmt}} to {r[1]:{fmt}}{unit}"


def _t1_ratio(net: str) -> tuple[float, float]:
    """Table 1's position error without prediction over with it (lowest, highest over its scenes)."""
    r = [float(wo.split()[0]) / float(w.split()[0]) for _, w, _, wo, _ in QUASAR_T1[net]]
    return min(r), max(r)


_T4: dict[tuple[str, str], list[tuple[float, float]]] = {
    **QUASAR_T4,
    # QUASAR table 4, the 50 cm view cell (our ``view_cell_m`` default): QuadStream and QUASAR ("Ours")
    ("QS", "lan"): [(32.67, 0.925), (34.27, 0.948), (29.57, 0.922), (27.57, 0.871)],
    ("QS", "cloud"): [(30.02, 0.906), (32.00, 0.937), (28.74, 0.908), (25.97, 0.846)],
    ("QUASAR", "lan"): [(32.10, 0.919), (34.04, 0.947), (30.90, 0.931), (28.66, 0.882)],
    ("QUASAR", "cloud"): [(29.94, 0.902), (30.94, 0.930), (29.65, 0.917), (27.38, 0.860)],
}
#: TSS table 4 per config (RL-p1..p3, VV-p1..p3): (LP, OS in, OS out samples in M, our DSSIM, SAS samples M, SAS DSSIM)
TSS_T4: dict[str, tuple[float, float, float, float, float, float]] = {
    "RL-p1": (8.2, 3.34, 1.70, 0.1208, 14.6, 0.1346), "RL-p2": (13.7, 5.44, 2.71, 0.1209, 13.6, 0.1478),
    "RL-p3": (18.3, 7.31, 3.69, 0.1208, 18.6, 0.1813), "VV-p1": (5.2, 3.86, 1.30, 0.0711, 21.6, 0.0679),
    "VV-p2": (8.4, 5.71, 1.87, 0.0712, 17.3, 0.0816), "VV-p3": (11.1, 7.20, 2.38, 0.0712, 20.2, 0.1526)}
_TSS_DSSIM = (min(r[3] - r[5] for r in TSS_T4.values()), max(r[3] - r[5] for r in TSS_T4.values()))
_TSS_SAMPLES = (min(sum(r[:3]) / r[4] for r in TSS_T4.values()), max(sum(r[:3]) / r[4] for r in TSS_T4.values()))
#: image warping table 3, error pixels (%) at server:client 2:1 and 10:1 per application
WARP_T3: dict[str, tuple[float, float]] = {"world-in-hand": (3.37, 3.54), "walk-through": (2.60, 2.73),
                                            "particle": (0.81, 0.93)}
_WARP_GROWTH = (min(b - a for a, b in WARP_T3.values()), max(b - a for a, b in WARP_T3.values()))
_MOVING = ("moving",)
_WHY_MOVING = "moving camera only: on a still one there is nothing to predict or to warp"
_CAUSE_BC4 = ("at the server's own pose (the still camera) both redraw the server's frame, so what differs is how "
              "each codes it (ATW's overscanned frame; MeshWarp's frame and its depth) and how MeshWarp's mesh meets "
              "the silhouettes: the papers' BC4-like depth moves their vertices. The diagnostic column is the same "
              "MeshWarp with exact depth (`depth_coding = \"lossless\"`): where it closes most of the still gap "
              "(2CylinderEngine's thin parts), the cause is the depth coding; where it changes nothing, the still cells "
              "differ by the colour coding, a few tenths of a dB either way. Under motion MeshWarp leads in every "
              "cell, as the paper says")
_Q = "QUASAR (quasar-quad-geometry-streaming)"
_S = "SAS (sas-shading-atlas-streaming)"
_T = "TSS (tessellated-shading-streaming)"
_W = "Image warping (image-warping-architecture)"
_D = "DDGI light probe streaming (light-probe-streaming)"
_QT4 = "1920x1080, 1500-frame game traces, four scenes (Robot Lab, Sun Temple, Viking Village, San Miguel), server 30 Hz"

CLAIMS: tuple[Claim, ...] = (
    Claim("Q-T4-1", _Q, "table 4", "MeshWarp (60°) beats ATW at 20 ± 10 ms latency", _num(_t4("MW (60°)", "ATW", "lan"), " dB PSNR"),
          f"{_QT4}, 20 ± 10 ms", "model PSNR", ((1, "MW60 lan"), (-1, "atw lan")), paper_range=_t4("MW (60°)", "ATW", "lan"),
          diagnostics=("MW60 lan exact depth",), cause=_CAUSE_BC4),
    Claim("Q-T4-2", _Q, "table 4", "MeshWarp (60°) beats ATW at 50 ± 20 ms latency", _num(_t4("MW (60°)", "ATW", "cloud"), " dB PSNR"),
          f"{_QT4}, 50 ± 20 ms", "model PSNR", ((1, "MW60 cloud"), (-1, "atw cloud")),
          paper_range=_t4("MW (60°)", "ATW", "cloud"), diagnostics=("MW60 cloud exact depth",), cause=_CAUSE_BC4),
    Claim("Q-T4-3", _Q, "table 4 and section 4.3", "MeshWarp (120°) gives better quality than MeshWarp (60°) "
          "(\"due to a higher shading rate in peripheral regions\")", _num(_t4("MW (120°)", "MW (60°)", "cloud"), " dB PSNR"),
          f"{_QT4}, 50 ± 20 ms", "model PSNR", ((1, "MW120 cloud"), (-1, "MW60 cloud")),
          paper_range=_t4("MW (120°)", "MW (60°)", "cloud"), diagnostics=("MW120 cloud 1:1",),
          cause="the paper's MeshWarp 120° doubles the resolution over a view three times as wide (tan 60° over "
          "tan 30°), so it samples the centre at two thirds of the display's rate. At 1920x1080 that costs little; at "
          "our 320x180 the models' texture and edges lie near the pixel rate, and the still camera shows the loss "
          "plainly. The diagnostic column is MeshWarp 120° sampling the centre as MeshWarp 60° does "
          "(`resolution_scale = 1`: 2.25x the paper's reference pixels): it separates the sampling from the wider view"),
    Claim("Q-T4-4", _Q, "table 4", "QUASAR beats MeshWarp (60°)", _num(_t4("QUASAR", "MW (60°)", "cloud"), " dB PSNR"), f"{_QT4}, 50 ± 20 ms, "
          "50 cm view cell", "model PSNR", ((1, "quasar cloud"), (-1, "MW60 cloud")),
          paper_range=_t4("QUASAR", "MW (60°)", "cloud"),
          diagnostics=("quasar cloud, reference every frame", "quasar cloud, exact quads",
                       "quasar cloud, exact quads every frame"),
          cause="the still cells are ties at the server's own pose, where both redraw the server's frame; on the three "
          "models only the colour coding differs there (the exact quads, with a lossless atlas, match the truth). Under "
          "motion QUASAR leads on every model, on 2CylinderEngine by a tenth of a dB only: its thin fins alias at "
          "320x180, so nearly all of either method's error there is the same sub-pixel misregistration of the "
          "model's interior (the ground truth against itself 5 ms of orbit apart scores 24 dB), which neither "
          "representation can mend; what was QUASAR's own, holes along depth edges where a pixel centre falls "
          "between two quads, its reference set now covers from behind (`underlap_px`, docs/methods.md). The "
          "diagnostic columns take the savings away one by one: a reference frame every frame (the paper sends one "
          "every fifth; a residual frame draws the cached reference mesh, whose colours were shaded from a pose up "
          "to four frames older); exact quads (a quad per pixel with its depth offsets and a lossless atlas, "
          "residual frames kept); and both, level with MeshWarp 60° on the engine: the representation itself "
          "loses nothing there, and the paper's margin comes from disocclusions that a single model in orbit "
          "barely has"),
    Claim("Q-T4-5", _Q, "table 4", "QUASAR beats MeshWarp (120°)", _num(_t4("QUASAR", "MW (120°)", "cloud"), " dB PSNR"), f"{_QT4}, 50 ± 20 ms, "
          "50 cm view cell", "model PSNR", ((1, "quasar cloud"), (-1, "MW120 cloud")),
          paper_range=_t4("QUASAR", "MW (120°)", "cloud")),
    Claim("Q-T4-6", _Q, "table 4", "QuadStream beats MeshWarp (60°), \"particularly under higher latency\"",
          _num(_t4("QS", "MW (60°)", "cloud"), " dB PSNR"), f"{_QT4}, 50 ± 20 ms, 50 cm view cell", "model PSNR",
          ((1, "quadstream cloud"), (-1, "MW60 cloud")), paper_range=_t4("QS", "MW (60°)", "cloud")),
    Claim("Q-T4-7", _Q, "section 4.3", "QUASAR's quality is \"comparable to, and often exceeding, QuadStream\" "
          "(here: no more than 1 dB below it)", _num(_t4("QUASAR", "QS", "cloud"), " dB PSNR"), f"{_QT4}, 50 ± 20 ms, 50 cm view cell",
          "model PSNR", ((1, "quasar cloud"), (-1, "quadstream cloud")), threshold=-1.0,
          paper_range=_t4("QUASAR", "QS", "cloud")),
    Claim("Q-T4-8", _Q, "section 4.3", "MeshWarp's quality \"significantly degrades with higher latency\" "
          "(20 ± 10 -> 50 ± 20 ms)", _num(_t4_loss("MW (60°)"), " dB PSNR lost"), _QT4, "model PSNR",
          ((1, "MW60 lan"), (-1, "MW60 cloud")), paper_range=_t4_loss("MW (60°)"), cameras=_MOVING, why_cameras=_WHY_MOVING),
    Claim("Q-T4-9", _Q, "table 4", "ATW loses quality with latency (20 ± 10 -> 50 ± 20 ms)", _num(_t4_loss("ATW"), " dB PSNR lost"),
          _QT4, "model PSNR", ((1, "atw lan"), (-1, "atw cloud")),
          paper_range=_t4_loss("ATW"),
          cameras=_MOVING, why_cameras=_WHY_MOVING),
    Claim("Q-T4-10", _Q, "table 4 and section 4.3", "QUASAR loses less than MeshWarp (60°) from 20 ± 10 to 50 ± 20 ms "
          "(measure: MeshWarp's loss minus QUASAR's)", _num(_t4_drop("QUASAR", "MW (60°)"), " dB"), f"{_QT4}, 50 cm view cell", "model PSNR",
          ((1, "MW60 lan"), (-1, "MW60 cloud"), (-1, "quasar lan"), (1, "quasar cloud")),
          paper_range=_t4_drop("QUASAR", "MW (60°)"), cameras=_MOVING, why_cameras=_WHY_MOVING),
    Claim("Q-F12-1", _Q, "section 4.3 (fig. 12)", "\"doubling both FOV and resolution substantially increases data "
          "rates by around 3-4x\" (MeshWarp 120° over 60°)", "3-4x", "fig. 12, averaged over both latencies",
          "kbit/s", ((1, "MW120 cloud"), (1, "MW60 cloud")), op="ratio", threshold=1.0, paper_range=(3.0, 4.0),
          cause="the bits follow what the wider view holds. Around a loaded model the 120° view's periphery is "
          "background, and the model itself is coded at two thirds of MeshWarp 60°'s sampling, so MeshWarp 120° "
          "sends fewer bits; the default scene, whose periphery holds walls and objects as the paper's game scenes "
          "do, sends more, as the paper says"),
    Claim("Q-F12-2", _Q, "section 4.3 (fig. 12)", "QuadStream's data rate is \"often an order of magnitude greater\" "
          "than the other methods' (here: over QUASAR's)", "about 10x", "fig. 12, 50 cm view cell", "kbit/s",
          ((1, "quadstream cloud"), (1, "quasar cloud")), op="ratio", threshold=1.0, paper_range=(10.0, 10.0)),
    Claim("Q-F12-3", _Q, "section 4.3 (fig. 12)", "ATW \"achieves the smallest data rate\" (here: against MeshWarp 60°)",
          "smallest of all", "fig. 12", "kbit/s", ((1, "atw cloud"), (1, "MW60 cloud")), op="ratio", expect="below",
          threshold=1.0),
    Claim("Q-F12-4", _Q, "section 4.3 (fig. 12)", "ATW \"achieves the smallest data rate\" (here: against QUASAR)",
          "smallest of all", "fig. 12", "kbit/s", ((1, "atw cloud"), (1, "quasar cloud")), op="ratio", expect="below",
          threshold=1.0),
    Claim("Q-T1-1", _Q, "table 1", "pose prediction cuts the position error at 20 ± 10 ms (without over with)",
          f"{_t1_ratio('lan')[0]:.2f}-{_t1_ratio('lan')[1]:.2f}x (e.g. 32 -> 9 cm)", "four game traces, kinematic prediction", "pose error",
          ((1, "pred none lan"), (1, "pred ca lan")), op="ratio", threshold=1.0, paper_range=_t1_ratio("lan"),
          cameras=_MOVING, why_cameras=_WHY_MOVING),
    Claim("Q-T1-2", _Q, "table 1", "pose prediction with Savitzky-Golay smoothing cuts the position error at "
          "50 ± 20 ms (without over with)", f"{_t1_ratio('cloud')[0]:.2f}-{_t1_ratio('cloud')[1]:.2f}x (e.g. 64 -> 53 cm)", "four game traces", "pose error",
          ((1, "pred none cloud"), (1, "pred ca_savgol cloud")), op="ratio", threshold=1.0,
          paper_range=_t1_ratio("cloud"), cameras=_MOVING, why_cameras=_WHY_MOVING),
    Claim("S-F13-1", _S, "fig. 13, section 5.6", "SAS keeps its quality under latency while image-based streaming "
          "loses it (measure: video's loss from 0 to 100 ms minus SAS's)", "direction only (MSSIM curves)",
          "server and client 120 Hz, 1920x1080, Robot Lab, Sponza, Viking Village", "model PSNR",
          ((1, "video ideal"), (-1, "video 100ms"), (-1, "sas ideal"), (1, "sas 100ms")),
          cameras=_MOVING, why_cameras=_WHY_MOVING),
    Claim("S-F13-2", _S, "fig. 13, section 5.6", "SAS beats MeshWarp under latency (\"the crossover point is already "
          "at 20 ms\"; here at 100 ms)", "crossover at 20 ms", "server and client 120 Hz, 1920x1080", "model PSNR",
          ((1, "sas 100ms"), (-1, "MW60 100ms")), cameras=_MOVING, why_cameras=_WHY_MOVING),
    Claim("S-F13-3", _S, "fig. 13, section 5.6", "SAS beats ATW under latency (here at 100 ms)", "crossover at 20 ms",
          "server and client 120 Hz, 1920x1080", "model PSNR", ((1, "sas 100ms"), (-1, "atw 100ms")),
          cameras=_MOVING, why_cameras=_WHY_MOVING),
    Claim("S-F14-1", _S, "fig. 14, section 5.7", "\"ATW cannot compete with the other methods quality-wise\" when the "
          "server runs slower than the client (SAS against ATW, server 8 Hz)", "direction only (MSSIM curves)",
          "server 7.5-60 Hz, client 120 Hz, zero latency", "model PSNR", ((1, "sas 8Hz"), (-1, "atw 8Hz")),
          cameras=_MOVING, why_cameras=_WHY_MOVING),
    Claim("S-F14-2", _S, "fig. 14, section 5.7", "\"ATW cannot compete with the other methods quality-wise\" "
          "(MeshWarp against ATW, server 8 Hz)", "direction only (MSSIM curves)",
          "server 7.5-60 Hz, client 120 Hz, zero latency", "model PSNR", ((1, "MW60 8Hz"), (-1, "atw 8Hz")),
          cameras=_MOVING, why_cameras=_WHY_MOVING),
    Claim("S-F15-1", _S, "fig. 15, section 5.8", "\"Even at a bitrate of 10 Mbps, ATW is already beaten by the other "
          "methods\" (SAS against ATW at a low bitrate: 500 kbit/s at our size)", "direction only (MSSIM curves)",
          "5-80 Mbit/s at 1920x1080, zero latency", "model PSNR", ((1, "sas 500k"), (-1, "atw 500k")),
          diagnostics=("sas lossless",),
          cause="on a still camera ATW codes the display's own pixels and refines them frame after frame; sas codes "
          "an atlas several times the display's pixels in the same bits, so within the run's second at 500 kbit/s it "
          "is still converging. Its lossless atlas (the diagnostic column) is above ATW on the still cells but the "
          "duck's, whose fine texture the resampling into the atlas and back loses: there the gap is that ceiling, "
          "elsewhere the rate. Under motion sas leads in every cell, as the paper's curves do"),
    Claim("T-T4-1", _T, "table 4, section 5.3", "TSS reaches better quality than SAS (lower DSSIM; measure: TSS's "
          "DSSIM minus SAS's)", _num(_TSS_DSSIM, " DSSIM over its six configs", "+.4f"),
          "1920x1080, Robot Lab and Viking Village, PVS configs p1-p3, 24 Mpix atlas", "model DSSIM",
          ((1, "tss ideal"), (-1, "sas ideal")), expect="below", paper_range=_TSS_DSSIM,
          evidence=lambda: tss_viewcell_evidence(),
          diagnostics=("tss matched", "tss matched lossless", "sas lossless"),
          cause="at its defaults tss shades one sample per covered pixel, a small fraction of sas's samples and "
          "below the paper's range (claim T-T4-2), so the measure compares unequal budgets. The diagnostic columns "
          "give tss a budget comparable to sas's (a moving budget of three samples per display pixel, with its "
          "slivers, flips and ring): lossless, against sas lossless, it is below sas's DSSIM on every still model "
          "and on the duck's and TextureTransformTest's orbits, the paper's claim, but not on the engine's orbit; "
          "lossy at the same crf the codec adds more error to tss's atlas of small triangles than to sas's blocks, "
          "so it comes level with sas on the still duck and engine at best, at several times sas's bits. The "
          "default scene, whose textures tss's triangle lattice samples worse than sas's blocks, trails in every "
          "column"),
    Claim("T-T4-2", _T, "table 4, section 5.3", "\"SAS generates significantly more shading samples\" than TSS "
          "(TSS's samples over SAS's)", f"{_TSS_SAMPLES[0]:.2f}-{_TSS_SAMPLES[1]:.2f}x over its six configs "
          "(the table has TSS above SAS in three)", "1920x1080, Robot Lab and Viking Village, PVS configs p1-p3",
          "samples", ((1, "tss ideal"), (1, "sas ideal")), op="ratio", expect="below", threshold=1.0,
          paper_range=_TSS_SAMPLES),
    Claim("W-T3-1", _W, "table 3", "error pixels (Lab dE > 20) grow as the server:client frame ratio grows "
          "(measure: 10:1 minus 2:1, percentage points)", _num(_WARP_GROWTH, " pp over its three applications"),
          "three applications, server:client 2:1 to 20:1", "error pixels", ((1, "warp 6Hz"), (-1, "warp 30Hz")),
          paper_range=_WARP_GROWTH, cameras=_MOVING, why_cameras=_WHY_MOVING),
    Claim("Q-43-1", _Q, "section 4.3", "MeshWarp's disocclusions \"become more frequent and pronounced\" with latency "
          "(holes over geometry that the point-splat `warp` could not draw from what arrived, 50 ± 20 ms minus "
          "20 ± 10 ms, percentage points; MeshWarp's mesh stretches over them instead)", "direction only",
          _QT4, "holes", ((1, "warp cloud"), (-1, "warp lan")), cameras=_MOVING, why_cameras=_WHY_MOVING),
    Claim("W-2V-1", _W, "section 3 (two reference views)", "a second reference view fills disocclusion holes "
          "(holes over geometry with two views minus one, percentage points, 50 ± 20 ms)", "direction only", "stereo pair of reference views",
          "holes", ((1, "warp 2 views cloud"), (-1, "warp cloud")), expect="below", cameras=_MOVING,
          why_cameras=_WHY_MOVING),
    Claim("B-ATW-1", f"{_S}; {_Q}", "baselines", "ATW beats plain video under latency (rotational reprojection)",
          "direction only", "50 ± 20 ms", "model PSNR", ((1, "atw cloud"), (-1, "video cloud")),
          cameras=_MOVING, why_cameras=_WHY_MOVING, diagnostics=("atw cloud turn", "video cloud turn"),
          cause="the moving camera on a loaded model is an orbit, whose rotation follows its translation so that the "
          "model stays in the middle of the view. ATW corrects the rotation only, so it carries the model across the "
          "view by the whole rotation where the late frame was nearly right. On a turn on the spot (the `turn` trace, "
          "the diagnostic columns) ATW leads video, as the papers' baseline assumes"),
    Claim("D-F6-1", _D, "figure 6", "visibility data takes more of the bandwidth than colour (\"color textures ... "
          "contribute less to the overall consumed bandwidth than visibility data\"; measure: the visibility "
          "stream's kbit/s over the colour stream's, both lossless HEVC)", "more (the raw visibility texture is "
          "3.24x the colour texture, section 3.2)", "2-8k probes at 10-30 Hz, three game scenes",
          "visibility over colour", ((1, "probes"),), threshold=1.0),
    Claim("D-F6-2", _D, "figure 6", "the consumed bandwidth grows with the GI update rate (measure: kbit/s at 30 Hz "
          "over 10 Hz)", "grows over 10, 20 and 30 Hz in every scene", "full volume encoding, three game scenes",
          "kbit/s", ((1, "probes 30Hz"), (1, "probes")), op="ratio", threshold=1.0, scenes=("default",),
          why_scenes="the default scene only: its lights change, so its probes do; a loaded model with GI added "
          "(`+gi`) has no moving light or object, so after the first update no probe changes, change thresholding "
          "sends none at any rate, and the rate cannot show (the models' runs stay in the study's store)"),
    Claim("D-34-1", _D, "section 3.4", "user-dependent probe selection lowers the bandwidth (measure: kbit/s sending "
          "the probes that light what the client can see over sending every active probe)", "direction only "
          "(the paper's selection strategies together with compression: 10-100x against uncompressed data)",
          "per-client selection, three game scenes", "kbit/s", ((1, "probes"), (1, "probes all")), op="ratio",
          expect="below", threshold=1.0,
          cause="the default scene is a room seen from inside: most of its active probes light something the client "
          "sees (`srv_probes_visible` against `srv_probes_active` in each run's `updates.csv`), so selection has "
          "little to leave out, and the two rates differ by a few per cent either way; around a loaded model, most of "
          "whose probes light nothing in view, selection cuts the rate, as the paper says"),
)


# --- configurations ---------------------------------------------------------------------------------------------------
TSS_VIEWCELLS = ROOT / "benchmarks" / "results" / "bench_tss_viewcells.json"
"""The TSS paper's own protocol (view cells p1-p3, a fixed 24 Mpix ``sas`` atlas, DSSIM), from
``benchmarks/bench_tss_viewcells.py``: its default grid at 320x180, and its matched runs (``tss`` at ``sas``'s
samples, lossy at ``sas``'s bits and lossless) at 320x180, 640x360 and 1280x720."""


def _size_px(size: str) -> int:
    w, h = (int(v) for v in size.split("x"))
    return w * h


def _bits(r: dict[str, Any], sas: dict[str, Any]) -> str:
    return f"{r['steady_kbps'] / max(sas['steady_kbps'], 1e-9):.2f}x"


def _matched_evidence(runs: dict[tuple[str, str, str, str], dict[str, Any]]) -> tuple[list[str], str]:
    """The matched runs' table (scene x size x cell) and its computed sentences: where ``tss`` at ``sas``'s samples
    leads ``sas`` lossless against lossless, where ``tss`` lossy at ``sas``'s bits does (the better of its runs at a
    crf for those bits: at ``sas``'s samples, ``tss matched @sas bits``, or at one sample per pixel, ``tss @sas
    bits``), and how the two gaps move with the resolution."""
    lines = ["| scene | size | cell | `sas` DSSIM / kbit/s | `tss` at `sas`'s samples: DSSIM (samples, bits x `sas`) "
             "| at `sas`'s bits: DSSIM (bits x) | `sas` lossless | `tss` lossless at `sas`'s samples | "
             "lossy / lossless `tss` - `sas` |", "|---|---|---|---|---|---|---|---|---|"]
    gaps: dict[tuple[str, str], list[tuple[int, str, float, float]]] = {}
    ratios: list[float] = []
    lead_bits, lead_ll, n = [], [], 0
    keys = list(dict.fromkeys((k[0], k[3], k[1]) for k in runs if k[2].startswith("tss matched")))
    order = list(dict.fromkeys(k[0] for k in keys))
    for sc, sz, cell in sorted(keys, key=lambda k: (order.index(k[0]), _size_px(k[1]), k[2])):
        a, t, al, tl = (runs.get((sc, cell, m, sz)) for m in ("sas", "tss matched", "sas lossless",
                                                             "tss matched lossless"))
        if not (a and (t or tl)):
            continue
        at_bits = [r for r in (runs.get((sc, cell, m, sz)) for m in ("tss matched @sas bits", "tss @sas bits")) if r]
        tb = min(at_bits, key=lambda r: r["model_dssim"]) if at_bits else None
        n += 1
        ratios.append((t or tl)["samples"] / max(a["samples"], 1.0))
        d_bits = tb["model_dssim"] - a["model_dssim"] if tb else float("nan")
        d_ll = tl["model_dssim"] - al["model_dssim"] if (tl and al) else float("nan")
        if d_bits < 0:
            lead_bits.append(f"{sc} {sz} {cell}")
        if d_ll < 0:
            lead_ll.append(f"{sc} {sz} {cell}")
        q_bits = tb["model_dssim"] / max(a["model_dssim"], 1e-9) if tb else float("nan")
        gaps.setdefault((sc, cell), []).append((_size_px(sz), sz, d_bits, d_ll, q_bits))
        lines.append(f"| {sc} | {sz} | {cell} | {a['model_dssim']:.5f} / {a['steady_kbps']:.0f} | "
                     + (f"{t['model_dssim']:.5f} ({ratios[-1]:.2f}x, {_bits(t, a)})" if t else f"({ratios[-1]:.2f}x)")
                     + " | "
                     + (f"{tb['model_dssim']:.5f} ({_bits(tb, a)})" if tb else "") + " | "
                     + " | ".join(f"{r['model_dssim']:.5f}" if r else "" for r in (al, tl))
                     + f" | {d_bits:+.5f} / {d_ll:+.5f} |")
    if not n:
        return [], ""
    text = (f"`tss` at `sas`'s samples ({min(ratios):.2f}-{max(ratios):.2f}x them; the paper's 0.48-1.61x) leads "
            f"`sas` lossless against lossless in {len(lead_ll)} of {n} cells"
            + (f" ({', '.join(lead_ll)})" if lead_ll else "") + ", and `tss` lossy at `sas`'s bits (the better of "
            f"`sas`'s samples and one per pixel, each at a crf for those bits) in {len(lead_bits)}"
            + (f" ({', '.join(lead_bits)})" if lead_bits else "") + ".")
    moved = []
    for (sc, cell), g in gaps.items():
        g = sorted(g)
        if len(g) < 2:
            continue
        (_, s0, b0, l0, q0), (_, s1, b1, l1, q1) = g[0], g[-1]
        moved.append(f"{sc} {cell} {s0} -> {s1}: lossy {b0:+.5f} ({q0:.2f}x `sas`'s) -> {b1:+.5f} ({q1:.2f}x), "
                     f"lossless {l0:+.5f} -> {l1:+.5f}")
    if moved:
        flips = sum(1 for g in gaps.values() if len(g) > 1 and any(
            math.copysign(1, sorted(g)[0][k]) != math.copysign(1, sorted(g)[-1][k]) for k in (2, 3)))
        shrink = sum(1 for g in gaps.values() if len(g) > 1 and abs(sorted(g)[-1][2]) < abs(sorted(g)[0][2]))
        shrink_q = sum(1 for g in gaps.values() if len(g) > 1 and
                       abs(math.log(max(sorted(g)[-1][4], 1e-9))) < abs(math.log(max(sorted(g)[0][4], 1e-9))))
        text += (f" As the resolution grows (`tss` - `sas` DSSIM, lossy at `sas`'s bits and lossless at its samples; "
                 f"{'; '.join(moved)}) the lossy gap shrinks in {shrink} of {len(moved)} scene-cells ({shrink_q} as "
                 f"the ratio of the two DSSIMs) and a gap changes sign in {flips}.")
    return lines, text


def tss_viewcell_evidence(path: Path = TSS_VIEWCELLS) -> str:
    """T-T4-1's evidence: per scene, how ``sas`` (fixed atlas) and ``tss`` change from the still cell to the largest
    view cell at 320x180, then the matched runs at each resolution (:func:`_matched_evidence`), read from the
    committed benchmark result."""
    import json

    try:
        d = json.loads(path.read_text())
        runs = {(r["scene"], r["cell"], r["run"], r.get("size", "320x180")): r for r in d["runs"]}
        cells = list(d["cells"])
    except (OSError, ValueError, KeyError, TypeError):
        return ""
    lo, hi = cells[0], cells[-1]
    lines = [f"| scene | sas DSSIM {lo} -> {hi} | tss DSSIM {lo} -> {hi} | sas samples {lo} -> {hi} | "
             f"tss samples {lo} -> {hi} | tss - sas DSSIM at {hi} |", "|---|---|---|---|---|---|"]
    trend, ahead = [], []
    for sc in dict.fromkeys(k[0] for k in runs):
        a0, a1, t0, t1 = (runs.get((sc, c, m, "320x180")) for c, m in ((lo, "sas"), (hi, "sas"), (lo, "tss"),
                                                                        (hi, "tss")))
        if not (a0 and a1 and t0 and t1):
            continue
        ds, dt = a1["model_dssim"] - a0["model_dssim"], t1["model_dssim"] - t0["model_dssim"]
        if ds > dt:
            trend.append(sc)
        if t1["model_dssim"] < a1["model_dssim"]:
            ahead.append(sc)
        lines.append(f"| {sc} | {a0['model_dssim']:.4f} -> {a1['model_dssim']:.4f} | {t0['model_dssim']:.4f} -> "
                     f"{t1['model_dssim']:.4f} | {a0['samples'] / 1e3:.0f}k -> {a1['samples'] / 1e3:.0f}k | "
                     f"{t0['samples'] / 1e3:.0f}k -> {t1['samples'] / 1e3:.0f}k | "
                     f"{t1['model_dssim'] - a1['model_dssim']:+.4f} |")
    if len(lines) == 2:
        return ""
    commits = d.get("commits") or [d.get("commit", "?")]
    at = (f"commit {commits[0]}" if len(commits) == 1 else
          f"commits {', '.join(commits)}" if len(commits) <= 3 else
          f"{len(commits)} commits up to {d.get('commit', '?')}, each row naming its own")
    text = (f"**The paper's own protocol** (`benchmarks/bench_tss_viewcells.py`, {at}: "
            f"{d.get('setting', '')}; `sas` with the paper's fixed 24 Mpix atlas; the view cells p1-p3 grow the PVS "
            "as the paper's table 1 does). At 320x180 and the defaults, the paper's trend, `sas` losing more quality "
            f"than `tss` as the cell grows, appears in {', '.join(trend) or 'no scene'}; `tss` ends ahead of `sas` in "
            f"{', '.join(ahead) or 'no scene'}. Where `sas`'s atlas never fills (a model fitted to the view: its PVS "
            "stays the model), the protocol has nothing to show; what remains there is the budget (`tss` at one "
            "sample per pixel shades several times fewer samples) and a per-sample gap of ours, which "
            "`docs/methods.md` (tss, \"The paper's protocol\") takes apart.\n\n" + "\n".join(lines))
    mlines, mtext = _matched_evidence(runs)
    if mlines:
        text += "\n\n**At the paper's sample counts and at larger sizes** (the matched runs). " + mtext + "\n\n" \
            + "\n".join(mlines)
    return text


def scene_path(name: str, gi: bool = False) -> str:
    """The cell's scene: the default scene without GI (the studies' scene), or a model; with ``gi`` (``probes``,
    whose subject is the GI) the default scene as it is, or the model with GI added (``+gi``)."""
    if name == "default":
        return "default" if gi else STUDY_SCENE
    return MODELS[name] + ("+gi" if gi else "")


def available_scenes(names: Sequence[str]) -> list[str]:
    return [n for n in names if n == "default" or os.path.isfile(MODELS[n])]


def run_config(run: str, scene: str, camera: str, g: dict[str, Any], truth_cache: str = "") -> Any:
    spec = RUNS[run]
    w, h = g["size"]
    trace = spec.get("trace", CAMERAS[camera]) if camera == "moving" else CAMERAS[camera]
    return RunConfig(method=spec["method"], method_params=dict(spec.get("params", {})), scene=scene_path(scene, spec.get("gi", False)),
                     trace=trace, network=spec.get("network", "ideal"), duration_s=g["duration_s"],
                     width=w, height=h, server_fps=spec.get("server_fps", 30), client_fps=60,
                     predictor=spec.get("predictor", "cv"), seed=0, flip_every=0,
                     metrics=spec.get("metrics", True), truth_cache=truth_cache)


# --- evaluation -------------------------------------------------------------------------------------------------------
def measure(claim: Claim, values: dict[str, float]) -> float:
    """The claim's measure from its runs' metric values (NaN when one is missing)."""
    v = [values.get(r, math.nan) for _, r in claim.terms]
    if claim.op == "ratio":
        return v[0] / v[1] if v[1] not in (0.0,) and not math.isnan(v[1]) else math.nan
    return float(sum(c * x for (c, _), x in zip(claim.terms, v)))


def verdict(claim: Claim, cells: dict[str, float]) -> tuple[str, str, float]:
    """(verdict, reason, median measure) from the measure per cell (``"scene / camera" -> value``)."""
    ok = {k: (v > claim.threshold if claim.expect == "above" else v < claim.threshold)
          for k, v in cells.items() if not math.isnan(v)}
    missing = [k for k, v in cells.items() if math.isnan(v)]
    if not ok:
        return "not measured", "no cell gave a number" + (f" (missing: {', '.join(missing)})" if missing else ""), math.nan
    med = statistics.median(cells[k] for k in ok)
    rule = f"{'>' if claim.expect == 'above' else '<'} {claim.threshold:g}"
    fails = [k for k, good in ok.items() if not good]
    tail = f"; not measured in {', '.join(missing)}" if missing else ""
    if fails:
        holds = [k for k, good in ok.items() if good]
        band = TIE_RATIO * abs(claim.threshold) if claim.op == "ratio" else TIE.get(claim.metric, 0.0)
        ties = [k for k in fails if abs(cells[k] - claim.threshold) <= band]
        tie = ""
        if ties:
            what = f"{TIE_RATIO:.0%} of {claim.threshold:g}" if claim.op == "ratio" else f"{band:g} {METRICS[claim.metric][1]}".strip()
            tie = (f"; {'all' if len(ties) == len(fails) else len(ties)} of the failing cells within {what} of it "
                   f"(a tie there, not a win: {', '.join(ties)})")
        return ("does not hold", f"measure {rule} fails in {len(fails)} of {len(ok)} cells ({', '.join(fails)})"
                + tie + (f"; holds in {', '.join(holds)}" if holds else "") + tail, med)
    if claim.paper_range is None:
        return "holds", f"measure {rule} in all {len(ok)} cells; the paper gives no magnitude to compare" + tail, med
    lo, hi = sorted(abs(x) for x in claim.paper_range)
    if lo / 2 <= abs(med) <= 2 * max(hi, 1e-12):
        return "holds", (f"measure {rule} in all {len(ok)} cells; median {med:.3g} within 2x of the paper's "
                         f"{claim.paper_range[0]:.3g}..{claim.paper_range[1]:.3g}") + tail, med
    return "holds with another magnitude", (f"measure {rule} in all {len(ok)} cells, but median {med:.3g} is more "
                                            f"than 2x off the paper's {claim.paper_range[0]:.3g}.."
                                            f"{claim.paper_range[1]:.3g}") + tail, med


def _metric(store: Any, cfg: Any, metric: str) -> float:
    """The stored run's value of ``metric`` (NaN when the run failed or is missing)."""
    key = METRICS[metric][0]
    if key.startswith("updates:"):
        try:
            return update_mean(store.load_updates(cfg.key()), key.split(":", 1)[1])
        except (OSError, IndexError, ValueError, TypeError):
            return math.nan
    if key.startswith("ratio:"):
        num, den = key.split(":", 1)[1].split("/")
        v = summary_floats(store, cfg, (num, den))
        return v[num] / v[den] if v[den] > 0 else math.nan
    return summary_floats(store, cfg, (key,))[key]


class ClaimsStudy(Study):
    """Every configuration the claims need, run into the study's store, the claims evaluated per cell, and the
    ledger (``claims.md``, ``claims.csv``, ``claims_cells.csv``; :data:`DOC` and :data:`RESULTS_DIR` by the full
    run)."""

    name = "claims"
    title = "Claims ledger"

    def __init__(self, out_dir: Path, quick: bool, claims: Sequence[Claim] = CLAIMS) -> None:
        super().__init__(out_dir, quick)
        self.claims = claims
        self.rows: list[dict[str, Any]] = []
        self.info: dict[str, Any] = {}

    def cells(self) -> None:
        """Run every configuration the claims need (cached in the store) and evaluate the claims: a row per claim
        and cell (:attr:`rows`), and the run info."""
        g = GRID[self.quick]
        scenes = available_scenes(g["scenes"]) or ["default"]
        cache = shared_cache_setting(self.out)
        cells = [(c, sc, cam) for c in self.claims for sc in scenes if c.scenes is None or sc in c.scenes
                 for cam in g["cameras"] if cam in c.cameras]
        need: dict[str, Any] = {}
        runs = {c.id: c.runs() if self.quick else c.all_runs() for c in self.claims}  # quick: no diagnostics
        for c, sc, cam in cells:
            for r in runs[c.id]:
                cfg = run_config(r, sc, cam, g, cache)
                need.setdefault(cfg.key(), cfg)
        todo = [c for c in need.values() if RUN_MISSING or self.store.has(c)]
        grid = self.run_grid(todo, g["workers"])
        for c, sc, cam in cells:
            cfgs = {r: run_config(r, sc, cam, g, cache) for r in runs[c.id]}
            vals = {r: _metric(self.store, cfg, c.metric) for r, cfg in cfgs.items()}
            self.rows.append({"claim": c.id, "scene": sc, "camera": cam, "metric": c.metric,
                              "measure": measure(c, vals), **{f"value[{r}]": v for r, v in vals.items()},
                              "commands": " ; ".join(f"{r}: {run_command(cfg)}" for r, cfg in cfgs.items()),
                              "config_keys": " ".join(cfg.key() for cfg in cfgs.values())})
        res = grid.result
        self.info = {"runs": len(todo), "not_run": len(need) - len(todo), "ran": len(res.ran), "cached": len(res.cached),
                     "failures": len(res.failures), "failed": [f.label for f in res.failures],
                     "elapsed_s": grid.runs_s, "history": grid.history, "scenes": scenes, "cameras": list(g["cameras"]),
                     "size": g["size"], "duration_s": g["duration_s"], "commit": grid.commit}

    def text(self) -> str:
        """The ledger, written to ``claims.md`` with its two tables."""
        text, summary = ledger(self.claims, self.rows, self.info, self.quick, self.cells_s)
        (self.out / "claims.md").write_text(text + "\n")
        self.table("claims.csv", summary)
        self.table("claims_cells.csv", self.rows)
        return text

    def publish(self, text: str) -> None:
        if DOC is None:
            return
        DOC.write_text(text + "\n")
        if RESULTS_DIR is not None:  # the tables the ledger is built from, beside it
            RESULTS_DIR.mkdir(parents=True, exist_ok=True)
            for f in (*self.tables, *([self.history_path] if self.history_path.is_file() else [])):
                shutil.copyfile(f, RESULTS_DIR / f.name)
        log.info("claims study: wrote %s and %s", DOC, RESULTS_DIR)

    def section(self, text: str) -> Section:
        body = text.split("\n", 2)[2] if text.startswith("# ") else text
        body = body.replace("\n### ", "\n#### ").replace("\n## ", "\n### ")  # under the report's section heading
        return super().section(body)


def ledger(claims: Sequence[Claim], rows: list[dict[str, Any]], info: dict[str, Any], quick: bool,
           took_s: float) -> tuple[str, list[dict[str, Any]]]:
    """The Markdown ledger and one summary row per claim (id, verdict, reason, median)."""
    summary: list[dict[str, Any]] = []
    w, h = info["size"]
    when = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    head = [
        "# Claims ledger", "",
        f"Generated by `splitrender study claims{' --quick' if quick else ''}` "
        f"(`splitrender/experiments/studies/claims.py`) on {when} at commit {info.get('commit', '?')}, in {took_s:.0f} s: "
        f"{info['runs']} runs ({info['ran']} run now, {info['cached']} from the study's result store, "
        f"{info['failures']} failed) at {w}x{h}, {info['duration_s']:g} s each, server 30 Hz, client 60 Hz unless a "
        f"run says otherwise, on {', '.join(info['scenes'])} x {', '.join(info['cameras'])} camera "
        f"({', '.join(f'{k}: `{v}` trace' for k, v in CAMERAS.items() if k in info['cameras'])}). "
        + store_history_text(info.get("history", [])) +
        " Nothing below is typed by hand except each paper's claim (its words, number, setting and the comparison "
        "rule, declared as data in the module); every number of ours and every verdict is computed from the runs.",
        "",
        "Verdicts: **holds** when the measure has the claimed sign in every cell (scene x camera) and its median is "
        "within 2x of the paper's range; **holds with another magnitude** when the sign is right everywhere but the "
        "median is outside that band; **does not hold** when the sign is wrong in any cell (a claim that one method "
        "beats another counts only where it holds on several real models and on both camera kinds). Scores are the "
        "model region's over the frames with content (`mean_model_*_content`). MeshWarp (MW 60, MW 120) is the papers' "
        "MeshWarp: `warp` with a mesh over BC4-like depth and no per-object motion (`extrapolate=false`), as in "
        "QUASAR's `mw_simulator`; our `warp` default also carries moving objects to the display time, which "
        "neither QUASAR nor QuadStream does. The paper's settings are large game "
        "scenes at 1920x1080: compare directions and rough magnitudes, not absolute values.",
        "",
    ]
    if quick:
        head += ["**Quick run**: one scene, one camera, a tiny size and a fraction of a second; it checks the "
                 "machinery and is not evidence.", ""]
    if info.get("not_run"):
        head += [f"**Incomplete**: {info['not_run']} of the runs the claims need were not run (the run was stopped "
                 "for time); their cells read n/a and each verdict says which cells it lacks.", ""]
    if info["failed"]:
        head += ["Failed runs: " + ", ".join(f"`{x}`" for x in info["failed"]), ""]
    table = ["| claim | paper, where | claim | paper's number | verdict | our median |",
             "|---|---|---|---|---|---|"]
    detail: list[str] = []
    counts: dict[str, int] = {}
    for c in claims:
        cells = {f"{r['scene']} / {r['camera']}": r["measure"] for r in rows if r["claim"] == c.id}
        v, why, med = verdict(c, cells)
        mine = [r for r in rows if r["claim"] == c.id]
        shown = [x for x in c.all_runs() if any(f"value[{x}]" in r for r in mine)] or c.runs()
        counts[v] = counts.get(v, 0) + 1
        unit = METRICS[c.metric][1] if c.op == "diff" else "x"
        summary.append({"claim": c.id, "paper": c.paper, "where": c.where, "verdict": v, "median": med,
                        "reason": why, "metric": c.metric, "op": c.op, "cells": len(cells)})
        table.append(f"| [{c.id}](#{c.id.lower()}) | {c.paper.split(' (')[0]}, {c.where} | {c.text} | "
                     f"{c.paper_number} | **{v}** | {_fmt(med)} {unit} |")
        measure_txt = (" + ".join(f"{'' if k == 0 else ''}{'-' if co < 0 else ''}{c.metric}[{r}]"
                                  for k, (co, r) in enumerate(c.terms)).replace("+ -", "- ")
                       if c.op == "diff" else f"{c.metric}[{c.terms[0][1]}] / {c.metric}[{c.terms[1][1]}]")
        detail += [f"### {c.id}", "",
                   f"- **Paper**: {c.paper}, {c.where}: {c.text}. Its number: {c.paper_number}. Its setting: {c.setting}.",
                   f"- **Measure**: {measure_txt} ({unit}), expected {c.expect} {c.threshold:g}"
                   + (f"; {c.why_cameras}" if c.why_cameras else "")
                   + (f"; {c.why_scenes}" if c.why_scenes else "") + ".",
                   f"- **Verdict**: **{v}**: {why}.", "",
                   "| scene | camera | ours | " + " | ".join(f"{c.metric}[{r}]" for r in shown) + " |",
                   "|---|---|---|" + "---|" * len(shown)]
        for r in mine:
            detail.append(f"| {r['scene']} | {r['camera']} | {_fmt(r['measure'])} | "
                          + " | ".join(_fmt(r.get(f'value[{x}]')) for x in shown) + " |")
        if c.cause and v != "holds":
            diag = [x for x in shown if x not in c.runs()]
            detail += ["", "**Why**" + (f" (diagnostic runs, outside the measure: {', '.join(f'`{x}`' for x in diag)})"
                                        if diag else "") + f": {c.cause}"]
        ev = c.evidence() if c.evidence is not None else ""
        if ev:
            detail += ["", ev]
        first = next((r for r in rows if r["claim"] == c.id), None)
        if first:
            detail += ["", "Reproduce (first cell; the other cells change `--scene` and `--trace`):", "", "```"]
            detail += [x.split(": ", 1)[1] for x in first["commands"].split(" ; ")] + ["```"]
        detail.append("")
    tally = ", ".join(f"{n} {k}" for k, n in sorted(counts.items()))
    text = "\n".join(head + [f"**{len(claims)} claims**: {tally}.", ""] + table + ["", "## Per claim", ""] + detail)
    return text, summary


def _fmt(v: Any) -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "n/a"
    return f"{v:.4g}" if isinstance(v, float) else str(v)


def run(out_dir: Path, quick: bool) -> Section:
    """Run the claims' configurations, write ``claims.md`` and the CSVs into ``out_dir`` (and :data:`DOC` when full)."""
    return ClaimsStudy(out_dir, quick).run()
