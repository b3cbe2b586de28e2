"""The answer first: one table per network of what each method buys and costs.

For every method on a network (its runs averaged over traces, :func:`~.store.summarise`):

* quality where it matters: PSNR over the foreground (the pixels where the ground truth
  shows geometry, ``mean_fg_psnr_db``) and over the whole frame, and FLIP (lower is
  better);
* its bits (``mean_kbps``: every stream, metadata included);
* what it costs: server and client milliseconds per frame as a ratio of the ground-truth
  render of the same frame on the same machine (``server / GT``, ``client / GT``), so the
  figure travels between machines better than milliseconds do;
* its rank on the speed-against-accuracy front: non-dominated sorting on (client cost
  ratio, lower is better; whole-frame PSNR, higher is better).  Rank 1 is the front
  itself (no other method on that network is both cheaper for the client and better),
  rank 2 the front once rank 1 is set aside, and so on.

Methods whose client holds and renders the whole scene (``MethodSpec.client_draws_scene``:
probes) are marked: they are a different kind of thin client, and their cost ratio says
so.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

from .store import Row, fnum

__all__ = ["HEADLINE_COLUMNS", "front_ranks", "headline_html", "headline_rows", "headline_markdown", "headline_text"]

HEADLINE_COLUMNS = ("rank", "method", "fg_psnr_db", "psnr_db", "flip", "kbps", "server_over_gt", "client_over_gt")


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


def _draws_scene(method: str) -> bool:
    try:
        from ..methods import get_method

        return bool(get_method(method).client_draws_scene)
    except Exception:  # noqa: BLE001 - a method from results no longer installed
        return False


def headline_rows(summary: Sequence[Row]) -> dict[str, list[Row]]:
    """Per network (in the order the summary has them), one row per method sorted by rank then PSNR."""
    by_net: dict[str, list[Row]] = {}
    for r in summary:
        by_net.setdefault(str(r["network"]), []).append(r)
    out: dict[str, list[Row]] = {}
    for net, rows in by_net.items():
        table: list[Row] = []
        for r in rows:
            gt = fnum(r.get("mean_gt_ms"))
            table.append({"method": str(r["method"]), "draws_scene": _draws_scene(str(r["method"])),
                          "fg_psnr_db": fnum(r.get("mean_fg_psnr_db")), "psnr_db": fnum(r.get("mean_psnr_db")),
                          "flip": fnum(r.get("mean_flip")), "kbps": fnum(r.get("mean_kbps")),
                          "server_over_gt": fnum(r.get("mean_server_ms")) / gt if gt > 0 else math.nan,
                          "client_over_gt": fnum(r.get("client_over_gt"))})
        ranks = front_ranks([(t["client_over_gt"], t["psnr_db"]) for t in table])
        for t, k in zip(table, ranks):
            t["rank"] = k
        table.sort(key=lambda t: (t["rank"] or 10**6, -(t["psnr_db"] if not math.isnan(t["psnr_db"]) else -1e9)))
        out[net] = table
    return out


def _fmt(v: Any, spec: str) -> str:
    if isinstance(v, float) and math.isnan(v):
        return "-"
    if spec == ".2f" and 0 < v < 0.005:
        return "<0.01"
    return format(v, spec)


def _cells(t: Row) -> list[str]:
    name = t["method"] + (" *" if t["draws_scene"] else "")
    return [str(t["rank"] or "-"), name, _fmt(t["fg_psnr_db"], ".1f"), _fmt(t["psnr_db"], ".1f"), _fmt(t["flip"], ".3f"),
            _fmt(t["kbps"], ".0f"), _fmt(t["server_over_gt"], ".2f"), _fmt(t["client_over_gt"], ".2f")]


_HEAD = ["front", "method", "fg PSNR dB", "PSNR dB", "FLIP", "kbit/s", "server / GT", "client / GT"]
_FOOT = ("fg PSNR: over the pixels where scene geometry is, in the ground truth or in the shown frame (the sky left "
         "out); front: rank on the speed-against-accuracy front (client cost against PSNR; 1 = no method is both cheaper "
         "and better); server / GT and client / GT: each side's milliseconds per frame divided by the ground-truth "
         "render's on this machine; * the client holds and renders the whole scene (it streams lighting).")


def headline_markdown(tables: dict[str, list[Row]]) -> str:
    """The headline tables as Markdown (the report's first section)."""
    lines = ["## The answer", ""]
    for net, rows in tables.items():
        lines += [f"**{net}**", "", "| " + " | ".join(_HEAD) + " |", "|" + "---|" * len(_HEAD)]
        lines += ["| " + " | ".join(_cells(t)) + " |" for t in rows]
        lines.append("")
    lines.append(_FOOT)
    return "\n".join(lines)


def headline_text(tables: dict[str, list[Row]]) -> str:
    """The headline tables for a terminal."""
    widths = [5, 10, 10, 7, 6, 7, 11, 11]
    out = []
    for net, rows in tables.items():
        out.append(f"{net}:")
        out.append("  " + " ".join(h.rjust(w) if i not in (1,) else h.ljust(w) for i, (h, w) in enumerate(zip(_HEAD, widths))))
        for t in rows:
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
        body = "".join("<tr>" + "".join(f"<td{' class=name' if i == 1 else ''}>{html.escape(c)}</td>"
                                        for i, c in enumerate(_cells(t))) + "</tr>" for t in rows)
        parts.append(f"<div><h3>{html.escape(net)}</h3><table><tr>{head}</tr>{body}</table></div>")
    parts.append(f"</div><p><small>{html.escape(_FOOT)}</small></p>")
    return "".join(parts)
