"""The answer first: one table per network of what each method buys and costs.

For every method on a network (its runs averaged over traces, :func:`~.store.summarise`):

* quality where it matters: PSNR over the scene's model (``mean_model_psnr_db``: the
  pixels where the ground truth shows the model, a loaded file's or a built-in scene's
  objects less its floor; :func:`splitrender.metrics.region_masks`) and over the whole
  frame, and FLIP (lower is better).  Each is the mean over the **frames with content**
  (``*_content``, :func:`splitrender.metrics.content_quality_summary`: every displayed frame
  from the first that shows an update on, the black start-up ticks before it left out),
  with the mean over all displayed frames beside it in brackets where the two differ
  (``*_all``).  A few black start-up ticks can outweigh every other frame's error in a short
  run (probes: FLIP 0.062 over all frames, 0.0002 over those with content), and how long
  start-up lasts depends on the run's network and session data, not on the method's
  picture; results from before the split have only the all-frames figure, shown alone;
* its steady bits (``steady_kbps``: every stream, metadata included, the one-off session
  data left out; ``mean_kbps`` for results from before it), and the one-off session data
  (``session_kb``, a scene upload) apart from it, so an upload is counted once;
* what it costs: server and client milliseconds per frame as a ratio of the ground-truth
  render of the same frame on the same machine (``server / GT``, ``client / GT``), so the
  figure travels between machines better than milliseconds do;
* its rank on the speed-against-accuracy front: non-dominated sorting on (client cost
  ratio, lower is better; model PSNR, or whole-frame PSNR where a run has no model
  score, higher is better).  Rank 1 is the front itself (no other method on that
  network is both cheaper for the client and better), rank 2 the front once rank 1 is
  set aside, and so on.

Methods whose client holds and renders the whole scene (``MethodSpec.client_draws_scene``:
probes) are a different class of client: they are listed apart, below the thin clients,
ranked among themselves, with their scene upload beside the score.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

from ..methods import get_method
from .store import Row, fnum

__all__ = ["HEADLINE_COLUMNS", "draws_scene", "front_ranks", "headline_html", "headline_rows", "headline_markdown", "headline_text"]

HEADLINE_COLUMNS = ("rank", "method", "model_psnr_db", "psnr_db", "flip", "kbps", "session_kb", "server_over_gt", "client_over_gt",
                    "model_psnr_db_all", "psnr_db_all", "flip_all")
"""A headline row's keys: quality over the frames with content (``model_psnr_db``, ``psnr_db``, ``flip``; NaN for
results from before the split) and over all displayed frames (``*_all``); ``kbps`` is the steady rate."""

_QUALITY_KEYS = {"model_psnr_db": "mean_model_psnr_db", "psnr_db": "mean_psnr_db", "flip": "mean_flip"}
"""Headline key -> summary column (over all frames; the same with ``_content`` over the frames with content)."""


def front_ranks(points: Sequence[tuple[float, float]]) -> list[int]:
    """Non-dominated sorting of (cost, quality) points, lower cost and higher quality better: each point's front
    number (1 = on the Pareto front); points with a NaN coordinate get 0 (unranked)."""
    ranks = [0] * len(points)
    left = [i for i, (c, q) in enumerate(points) if not (math.isnan(c) or math.isnan(q))]
    rank = 1
    while left:
        front = [i for i in left
                 if not any(points[j][0] <= points[i][0] and points[j][1] >= points[i][1] and points[j] != points[i]
                            for j in left)]
        for i in front:
            ranks[i] = rank
        left = [i for i in left if i not in front]
        rank += 1
    return ranks


def draws_scene(method: str) -> bool:
    """Whether ``method``'s client holds and renders the whole scene (a different class of client: probes)."""
    try:
        return bool(get_method(method).client_draws_scene)
    except Exception:  # noqa: BLE001 - a method from results no longer installed
        return False


def headline_rows(summary: Sequence[Row]) -> dict[str, list[Row]]:
    """Per network (in the order the summary has them), one row per method: the thin clients sorted by rank then
    quality, then the methods whose client draws the scene (``draws_scene``), ranked among themselves."""
    by_net: dict[str, list[Row]] = {}
    for r in summary:
        by_net.setdefault(str(r["network"]), []).append(r)
    out: dict[str, list[Row]] = {}
    for net, rows in by_net.items():
        table: list[Row] = []
        for r in rows:
            gt = fnum(r.get("mean_gt_ms"))
            steady = fnum(r.get("steady_kbps"))   # the upload is in session_kb: not in the rate as well
            table.append({"method": str(r["method"]), "draws_scene": draws_scene(str(r["method"])),
                          **{k: fnum(r.get(f"{col}_content")) for k, col in _QUALITY_KEYS.items()},
                          **{f"{k}_all": fnum(r.get(col)) for k, col in _QUALITY_KEYS.items()},
                          "kbps": steady if not math.isnan(steady) else fnum(r.get("mean_kbps")),
                          "session_kb": fnum(r.get("session_kb")),
                          "server_over_gt": fnum(r.get("mean_server_ms")) / gt if gt > 0 else math.nan,
                          "client_over_gt": fnum(r.get("client_over_gt"))})
        sorted_rows: list[Row] = []
        for cls in (False, True):
            part = [t for t in table if t["draws_scene"] == cls]
            ranks = front_ranks([(t["client_over_gt"], _quality(t)) for t in part])
            for t, k in zip(part, ranks):
                t["rank"] = k
            part.sort(key=lambda t: (t["rank"] or 10**6, -(_quality(t) if not math.isnan(_quality(t)) else -1e9)))
            sorted_rows += part
        out[net] = sorted_rows
    return out


def _score(t: Row, key: str) -> float:
    """``key``'s headline figure: over the frames with content, over all frames for results from before the split."""
    v = t.get(key, math.nan)
    return v if not math.isnan(v) else t.get(f"{key}_all", math.nan)


def _quality(t: Row) -> float:
    """The score a method is ranked by (frames with content): model PSNR where the run has it, whole-frame PSNR
    otherwise."""
    m = _score(t, "model_psnr_db")
    return m if not math.isnan(m) else _score(t, "psnr_db")


def _fmt(v: Any, spec: str) -> str:
    if isinstance(v, float) and math.isnan(v):
        return "-"
    if spec == ".2f" and 0 < v < 0.005:
        return "<0.01"
    return format(v, spec)


def _both(t: Row, key: str, spec: str) -> str:
    """The figure over the frames with content, then the one over all frames in brackets where it reads differently."""
    content, every = _fmt(t.get(key, math.nan), spec), _fmt(t.get(f"{key}_all", math.nan), spec)
    if content == "-":
        return every
    return content if every in (content, "-") else f"{content} ({every})"


def _cells(t: Row) -> list[str]:
    name = t["method"] + (" *" if t["draws_scene"] else "")
    once = t.get("session_kb", math.nan)
    return [str(t["rank"] or "-"), name, _both(t, "model_psnr_db", ".1f"), _both(t, "psnr_db", ".1f"), _both(t, "flip", ".3f"),
            _fmt(t["kbps"], ".0f"), _fmt(once, ".0f") if once >= 0.5 else "-", _fmt(t["server_over_gt"], ".2f"),
            _fmt(t["client_over_gt"], ".2f")]


_HEAD = ["front", "method", "model PSNR dB", "PSNR dB", "FLIP", "kbit/s", "upload kB", "server / GT", "client / GT"]
_FOOT = ("model PSNR: over the pixels where the ground truth shows the scene's model (a loaded file's model, or a "
         "built-in scene less its floor; the sky and the floor left out); PSNR: the whole frame; PSNR and FLIP are means "
         "over the frames with content (every displayed frame from the first that shows an update on: the black "
         "start-up ticks before it are left out), and in brackets, where it differs, over all displayed frames; front: "
         "rank on the speed-against-accuracy front (client cost against model PSNR over the frames with content; 1 = no "
         "method is both cheaper and better), ranked within each class; kbit/s: the steady rate, every stream but the "
         "one-off upload; upload kB: one-off session data; "
         "server / GT and client / GT: each side's milliseconds per frame divided by the ground-truth render's on this "
         "machine; * a different class of client, listed apart: it holds and renders the whole scene (uploaded once) "
         "and streams only lighting.")
_CLASS_ROW = "client renders the scene:"


def _class_breaks(rows: list[Row]) -> list[Row | None]:
    """The rows with ``None`` where the class changes to clients that render the scene."""
    out: list[Row | None] = []
    for i, t in enumerate(rows):
        if t["draws_scene"] and (i == 0 or not rows[i - 1]["draws_scene"]):
            out.append(None)
        out.append(t)
    return out


def headline_markdown(tables: dict[str, list[Row]]) -> str:
    """The headline tables as Markdown (the report's first section)."""
    lines = ["## The answer", ""]
    for net, rows in tables.items():
        lines += [f"**{net}**", "", "| " + " | ".join(_HEAD) + " |", "|" + "---|" * len(_HEAD)]
        lines += ["| " + " | ".join(_cells(t) if t else ["", f"*{_CLASS_ROW}*"] + [""] * (len(_HEAD) - 2)) + " |"
                  for t in _class_breaks(rows)]
        lines.append("")
    lines.append(_FOOT)
    return "\n".join(lines)


def headline_text(tables: dict[str, list[Row]]) -> str:
    """The headline tables for a terminal."""
    widths = [5, 10, 13, 11, 13, 7, 9, 11, 11]
    out = []
    for net, rows in tables.items():
        out.append(f"{net}:")
        out.append("  " + " ".join(h.rjust(w) if i not in (1,) else h.ljust(w) for i, (h, w) in enumerate(zip(_HEAD, widths))))
        for t in _class_breaks(rows):
            if t is None:
                out.append("  " + " " * (widths[0] + 1) + _CLASS_ROW)
                continue
            cells = _cells(t)
            out.append("  " + " ".join(c.rjust(w) if i not in (1,) else c.ljust(w) for i, (c, w) in enumerate(zip(cells, widths))))
    out.append(_FOOT)
    return "\n".join(out)


def headline_html(tables: dict[str, list[Row]]) -> str:
    """The headline tables as HTML (the report opens with them)."""
    import html

    parts = ["<h2 id='answer'>The answer</h2><div class='nets'>"]     # the networks side by side: the chart fits below
    for net, rows in tables.items():
        head = "".join(f"<th>{html.escape(h)}</th>" for h in _HEAD)
        body = "".join(
            f"<tr class=cls><td></td><td colspan={len(_HEAD) - 1}><i>{html.escape(_CLASS_ROW)}</i></td></tr>" if t is None else
            "<tr>" + "".join(f"<td{' class=name' if i == 1 else ''}>{html.escape(c)}</td>" for i, c in enumerate(_cells(t))) + "</tr>"
            for t in _class_breaks(rows))
        parts.append(f"<div><h3>{html.escape(net)}</h3><table><tr>{head}</tr>{body}</table></div>")
    parts.append(f"</div><p><small>{html.escape(_FOOT)}</small></p>")
    return "".join(parts)
