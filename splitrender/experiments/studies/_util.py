"""Helpers the studies share (a leading underscore keeps this module out of study discovery)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

STUDY_SCENE = "default+nogi"
"""The scene of the studies that set methods beside each other and beside their papers (sas, tss, warp, quads,
papers, cost): the default scene without its global illumination.  The papers measured their methods without
DDGI, and GI's light probes cost about as much per update as rendering the frame three times on llvmpipe
(``benchmarks/bench_gi.py``); the demo's own runs use the default scene as it is, with GI, and the probes study is
where GI is the subject."""


def update_mean(ups: list[dict[str, Any]], key: str) -> float:
    """Mean of ``key`` over a run's updates, the first left out (it compiles shaders); NaN when absent."""
    v = [float(u[key]) for u in ups[1:] if key in u and u[key] == u[key]]
    return float(np.mean(v)) if v else float("nan")


def save_figure(fig: Any, path: Path) -> Path:
    """Lay out ``fig``, write it to ``path`` as PNG at 110 dpi and close it."""
    import matplotlib.pyplot as plt

    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
