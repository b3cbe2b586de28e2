"""The HTML report of a results folder (a sweep's ``runs.csv``/``frames.csv`` or the demo's).

``build_report(DIR)`` draws every chart the results support (see :mod:`.charts`) into
``DIR/figures`` as PNG + SVG + CSV and writes ``DIR/report.html``: one self-contained
file (PNGs embedded as base64) with the charts, the tables behind them, the runs table,
the resolved configs, and any extra sections (the demo's notes and the per-method
studies, kept in ``DIR/report_meta.json`` so ``splitrender report DIR`` rebuilds the
same report).
"""

from __future__ import annotations

import argparse
import base64
import html
import json
import logging
import math
import re
from pathlib import Path
from typing import Any, Sequence

from ..errors import ConfigError
from .charts import (FAIL_HOLE_PCT, FAIL_PSNR_DB, Chart, bitrate_stacked, client_cost, failure_mask, method_order, quality_timeline,
                     quality_vs_frame_ratio, quality_vs_latency, rate_distortion, run_timeline, speed_accuracy)
from .headline import headline_html, headline_rows
from .sections import Section, load_study_sections
from .store import ResultStore, Row, fnum, load_results, read_csv, summarise

log = logging.getLogger(__name__)

META_FILE = "report_meta.json"
RUN_COLUMNS = ("run", "method", "params", "network", "trace", "seed", "width", "height", "server_fps", "client_fps", "frames",
               "mean_psnr_db", "psnr_mse_db", "p5_psnr_db", "mean_ssim", "mean_flip", "flip_frames", "mean_model_psnr_db",
               "mean_interior_psnr_db", "mean_edge_psnr_db", "mean_model_flip", "mean_fg_psnr_db", "mean_fg_flip",
               "mean_hole_pct", "mean_lab_err_pct",
               "mean_kbps", "steady_kbps", "session_kb", "mean_update_age_ms", "mean_server_ms", "mean_client_ms", "mean_gt_ms", "lost_frames", "keyframes",
               "mean_psnr_db_content", "mean_flip_content", "mean_model_psnr_db_content", "model_psnr_mse_db_content",
               "frames_before_content")


# ---------------------------------------------------------------------------------
# Small HTML helpers
# ---------------------------------------------------------------------------------


def markdown_to_html(md: str) -> str:
    """A small Markdown subset: headings, lists, fenced code, paragraphs, `code`, **bold**, *em*."""
    out: list[str] = []
    para: list[str] = []
    in_list = False
    in_code = False

    def inline(s: str) -> str:
        s = html.escape(s)
        s = re.sub(r"`([^`]+)`", r"<code>\1</code>", s)
        s = re.sub(r"\*\*([^*]+)\*\*", r"<b>\1</b>", s)
        return re.sub(r"(?<![\w*])\*([^*]+)\*(?!\w)", r"<i>\1</i>", s)

    def flush() -> None:
        nonlocal in_list
        if para:
            out.append("<p>" + inline(" ".join(para)) + "</p>")
            para.clear()
        if in_list:
            out.append("</ul>")
            in_list = False

    for line in md.splitlines():
        if line.strip().startswith("```"):
            flush()
            out.append("</pre>" if in_code else "<pre>")
            in_code = not in_code
            continue
        if in_code:
            out.append(html.escape(line))
            continue
        s = line.strip()
        m = re.match(r"^(#{1,4})\s+(.*)$", s)
        if m:
            flush()
            lvl = min(6, len(m.group(1)) + 2)
            out.append(f"<h{lvl}>{inline(m.group(2))}</h{lvl}>")
        elif re.match(r"^[-*]\s+", s):
            if para:
                out.append("<p>" + inline(" ".join(para)) + "</p>")
                para.clear()
            if not in_list:
                out.append("<ul>")
                in_list = True
            out.append("<li>" + inline(re.sub(r"^[-*]\s+", "", s)) + "</li>")
        elif not s:
            flush()
        else:
            if in_list:
                flush()
            para.append(s)
    flush()
    if in_code:
        out.append("</pre>")
    return "\n".join(out)


def _cell(v: Any) -> str:
    if isinstance(v, float):
        return "" if math.isnan(v) else f"{v:.4g}"
    return html.escape(str(v))


def html_table(rows: Sequence[Row], columns: Sequence[str] | None = None, max_rows: int = 200) -> str:
    if not rows:
        return "<p><i>(empty)</i></p>"
    cols = list(columns) if columns else list(dict.fromkeys(k for r in rows for k in r))
    cols = [c for c in cols if any(c in r for r in rows)]
    head = "".join(f"<th>{html.escape(c)}</th>" for c in cols)
    body = "\n".join("<tr>" + "".join(f"<td>{_cell(r.get(c, ''))}</td>" for c in cols) + "</tr>" for r in rows[:max_rows])
    more = f"<p><i>{len(rows) - max_rows} more rows in the CSV</i></p>" if len(rows) > max_rows else ""
    return f'<div class="tbl"><table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table></div>{more}'


def embed_image(path: Path, alt: str = "") -> str:
    """An ``<img>`` with the PNG (or SVG) inlined as base64 so the HTML stands alone."""
    mime = "image/svg+xml" if path.suffix.lower() == ".svg" else "image/png"
    b64 = base64.b64encode(path.read_bytes()).decode("ascii")
    return f'<img alt="{html.escape(alt)}" src="data:{mime};base64,{b64}">'


def _chart_html(ch: Chart, root: Path) -> str:
    parts = [f'<figure id="{ch.name}">', embed_image(ch.png, ch.name), f"<figcaption>{markdown_to_html(ch.caption)}",
             f'<br><small>files: {html.escape(str(ch.png.relative_to(root)))}, {html.escape(str(ch.svg.relative_to(root)))}'
             + (f", data {html.escape(str(ch.csv.relative_to(root)))}" if ch.csv else "") + "</small></figcaption>"]
    if ch.csv:
        parts.append(f"<details><summary>data behind this chart</summary>{html_table(read_csv(ch.csv))}</details>")
    parts.append("</figure>")
    return "\n".join(parts)


def section_html(sec: Section, root: Path) -> str:
    """A study's section: Markdown text, its figures (embedded) and tables."""
    took = f"<p><small>study time: {sec.elapsed_s:.0f} s wall clock</small></p>" if sec.elapsed_s is not None else ""
    parts = [f"<section><h2>{html.escape(sec.title)}</h2>", took, markdown_to_html(sec.text_md)]
    for f in sec.figures:
        p = Path(f)
        p = p if p.is_absolute() else root / p
        if p.is_file():
            parts.append(f"<figure>{embed_image(p, p.stem)}<figcaption><small>{html.escape(p.name)}</small></figcaption></figure>")
        else:
            parts.append(f'<p class="err">figure missing: {html.escape(str(f))}</p>')
    for t in sec.tables:
        p = Path(t)
        p = p if p.is_absolute() else root / p
        if p.is_file():
            parts.append(f"<h4>{html.escape(p.name)}</h4>" + html_table(read_csv(p)))
        else:
            parts.append(f'<p class="err">table missing: {html.escape(str(t))}</p>')
    parts.append("</section>")
    return "\n".join(parts)


CSS = """body{font-family:system-ui,sans-serif;max-width:1200px;margin:1em auto;padding:0 1em;color:#222}
img{max-width:100%}figure{margin:1.5em 0}figcaption{font-size:90%;color:#444}
table{border-collapse:collapse;font-size:12px}td,th{border:1px solid #ccc;padding:2px 6px;text-align:right}
th{background:#f0f0f0}.tbl{overflow-x:auto}pre{background:#f6f6f6;padding:.5em;overflow-x:auto;font-size:12px}
.err{color:#a00;font-weight:bold}code{background:#f3f3f3;padding:0 2px}
.nets{display:flex;flex-wrap:wrap;gap:0 1.5em}.nets h3{margin:.4em 0}td.name{text-align:left}"""


# ---------------------------------------------------------------------------------
# The report
# ---------------------------------------------------------------------------------


def save_meta(root: Path, title: str, intro_md: str, sections: Sequence[Section]) -> Path:
    """Keep the demo's notes and study sections next to the results (for ``splitrender report``)."""
    meta = {"title": title, "intro_md": intro_md,
            "sections": [{"title": s.title, "text_md": s.text_md, "figures": [str(f) for f in s.figures],
                          "tables": [str(t) for t in s.tables]} for s in sections]}
    p = root / META_FILE
    p.write_text(json.dumps(meta, indent=1))
    return p


def load_meta(root: Path) -> tuple[str | None, str, list[Section]]:
    p = root / META_FILE
    if not p.is_file():
        return None, "", []
    d = json.loads(p.read_text())
    secs = [Section(s["title"], s.get("text_md", ""), [Path(f) for f in s.get("figures", [])], [Path(t) for t in s.get("tables", [])])
            for s in d.get("sections", [])]
    return d.get("title"), d.get("intro_md", ""), secs


def worst_run(runs: Sequence[Row]) -> str | None:
    """The key of the run with the lowest mean PSNR."""
    cand = [r for r in runs if not math.isnan(fnum(r.get("mean_psnr_db"))) and r.get("run")]
    return str(min(cand, key=lambda r: fnum(r["mean_psnr_db"]))["run"]) if cand else None


def build_charts(root: Path, runs: Sequence[Row], frames: Sequence[Row], run_key: str | None = None) -> list[tuple[str, Chart]]:
    """Every chart the results support, with a heading each."""
    figdir = root / "figures"
    out: list[tuple[str, Chart | None]] = [
        ("Quality against latency", quality_vs_latency(runs, figdir)),
    ]
    nets = list(dict.fromkeys(str(r["network"]) for r in runs))
    tl_net = "cloud" if "cloud" in nets else (max(runs, key=lambda r: fnum(r.get("net_delay_ms")))["network"] if runs else None)
    if frames and tl_net is not None:
        traces = list(dict.fromkeys(str(f.get("trace")) for f in frames if f.get("network") == tl_net))
        out.append((f"Quality over time ({tl_net})", quality_timeline(frames, figdir, str(tl_net), traces[0] if traces else None)))
    out += [
        ("Bitrate by stream", bitrate_stacked(runs, figdir)),
        ("Client cost", client_cost(runs, figdir)),
        ("Rate-distortion", rate_distortion(runs, figdir)),
        ("Quality against the server:client frame ratio", quality_vs_frame_ratio(runs, figdir)),
        ("Speed against accuracy", speed_accuracy(runs, figdir)),
    ]
    key = run_key or worst_run(runs)
    if key:
        sel = [r for r in runs if r.get("run") == key]
        if not sel:
            raise ConfigError(f"report --run {key}: no such run in {root} (keys are in runs.csv)")
        r = sel[0]
        fr = [f for f in frames if f.get("run") == key]
        store = ResultStore(root)
        if not fr and store.run_dir(key).is_dir():
            fr = store.load_frames(key)
        ups = store.load_updates(key) if store.run_dir(key).is_dir() else []
        which = "chosen" if run_key else "worst-PSNR"
        title = f"{which} run {key}: {r['method']} {r.get('params') or ''} on {r['network']}, trace {r.get('trace')}"
        out.append((f"Per-frame timelines ({which} run)", run_timeline(fr, ups, figdir, title, fnum(r.get("server_fps")) or 30.0)))
    return [(h, c) for h, c in out if c is not None]


def build_report(root: str | Path, run_key: str | None = None, title: str | None = None, intro_md: str | None = None,
                 sections: Sequence[Section] | None = None) -> Path:
    """Write ``root/report.html`` (self-contained) and ``root/figures/*``; returns the HTML path."""
    root = Path(root)
    if (root / "runs.csv").is_file() or (root / "summary.csv").is_file() or not (root / "studies").is_dir():
        runs, frames = load_results(root)
    else:   # a folder of studies alone (``splitrender study --out DIR``)
        runs, frames = [], []
    mtitle, mintro, msections = load_meta(root)
    title = title or mtitle or f"splitrender results: {root.name}"
    intro_md = intro_md if intro_md is not None else mintro
    if sections is None:   # the demo's own (older folders kept them in the meta file) and every study run into root
        studies = load_study_sections(root)
        titles = {s.title for s in studies}
        sections = [s for s in msections if s.title not in titles] + studies
    sections = list(sections)
    charts = build_charts(root, runs, frames, run_key)

    methods = method_order([str(r["method"]) for r in runs])
    parts = [f"<!doctype html><html><head><meta charset='utf-8'><title>{html.escape(title)}</title><style>{CSS}</style></head><body>",
             f"<h1>{html.escape(title)}</h1>",
             f"<p>{len(runs)} runs; methods: {', '.join(methods)} (baselines: video, atw); networks: "
             f"{html.escape(', '.join(dict.fromkeys(str(r['network']) for r in runs)))}.</p>" if runs else
             "<p>Studies only: this folder has no demo runs.</p>"]
    missing = [b for b in ("video", "atw") if b not in methods]
    if missing and runs:
        parts.append(f'<p class="err">These results lack the baseline(s) {", ".join(missing)}: the charts cannot show them.</p>')
    # the answer first: what each method buys and costs per network, then speed against accuracy
    if runs:
        parts.append(headline_html(headline_rows(summarise(runs))))
        for heading, ch in [(h, c) for h, c in charts if c.name == "speed_vs_accuracy"]:
            parts.append(f"<h2>{html.escape(heading)}</h2>")
            parts.append(_chart_html(ch, root))
        charts = [(h, c) for h, c in charts if c.name != "speed_vs_accuracy"]
    if intro_md:
        parts.append(markdown_to_html(intro_md))
    parts.append(f"<p>Failure frames: PSNR below {FAIL_PSNR_DB:g} dB or more than {FAIL_HOLE_PCT:g}% hole pixels where the ground truth shows geometry.</p>")
    parts.append("<h2>Contents</h2><ul>" + "".join(f'<li><a href="#{c.name}">{html.escape(h)}</a></li>' for h, c in charts)
                 + "".join(f"<li>{html.escape(s.title)}" + (f" ({s.elapsed_s:.0f} s)" if s.elapsed_s is not None else "")
                           + "</li>" for s in sections) + "</ul>")
    for heading, ch in charts:
        parts.append(f"<h2>{html.escape(heading)}</h2>")
        parts.append(_chart_html(ch, root))
    parts.append("<h2>Runs</h2>" + html_table(runs, RUN_COLUMNS))
    fails = _failure_table(runs, frames)
    if fails:
        parts.append(f"<h3>Failure frames per run</h3>{html_table(fails)}")
    for sec in sections:
        parts.append(section_html(sec, root))
    parts.append("<h2>Resolved configs</h2>")
    store = ResultStore(root)
    for r in runs:
        p = store.run_dir(str(r.get("run"))) / "config.toml"
        if p.is_file():
            parts.append(f"<details><summary>{html.escape(str(r.get('run')))}: {html.escape(str(r['method']))} "
                         f"{html.escape(str(r.get('params') or ''))} / {html.escape(str(r['network']))} / "
                         f"{html.escape(str(r.get('trace')))}</summary><pre>{html.escape(p.read_text())}</pre></details>")
    parts.append("</body></html>")
    out = root / "report.html"
    out.write_text("\n".join(parts))
    log.info("report written to %s (%d charts, %d sections)", out, len(charts), len(sections))
    return out


def _failure_table(runs: Sequence[Row], frames: Sequence[Row]) -> list[Row]:
    by_run: dict[str, list[Row]] = {}
    for f in frames:
        by_run.setdefault(str(f.get("run")), []).append(f)
    out = []
    for r in runs:
        fr = by_run.get(str(r.get("run")), [])
        if fr:
            n = sum(failure_mask(fr))
            out.append({"run": r.get("run"), "method": r["method"], "params": r.get("params"), "network": r["network"],
                        "frames": len(fr), "failure_frames": n, "failure_pct": 100.0 * n / len(fr)})
    return out


def main_report(ns: argparse.Namespace) -> int:
    """``splitrender report DIR [--run KEY]``."""
    p = build_report(ns.dir, run_key=ns.run)
    print(f"report: {p}")
    return 0


__all__ = ["build_charts", "build_report", "embed_image", "html_table", "load_meta", "main_report", "markdown_to_html", "save_meta",
           "section_html", "worst_run"]
