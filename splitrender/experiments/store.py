"""Results I/O: per-run folders keyed by ``RunConfig.key()`` and the tidy tables.

Layout of a results folder (sweep or demo)::

    DIR/runs/<key>/config.toml     the full resolved RunConfig
    DIR/runs/<key>/summary.csv     one row (RunResult.summary)
    DIR/runs/<key>/frames.csv      one row per displayed frame
    DIR/runs/<key>/updates.csv     one row per server frame
    DIR/runs.csv                   one row per run: summary + ``param_*`` + network columns
    DIR/frames.csv                 one row per displayed frame of every run, with ``run`` (the key)

Tables are lists of dicts (no pandas dependency); :func:`read_csv` turns numeric
text back into floats/ints so charts and tests can use the values directly.
"""

from __future__ import annotations

import csv
import logging
import math
from pathlib import Path
from typing import Any, Iterable, Sequence

from ..errors import ConfigError
from ..netsim import parse_path
from ..sim.config import RunConfig, to_toml
from ..tabular import write_csv as write_table

log = logging.getLogger(__name__)

Row = dict[str, Any]

#: Columns that are wall-clock measurements on this machine: they differ between two
#: executions of the same config; everything else in a run's tables is deterministic.
TIMING_COLUMNS = frozenset({
    "server_ms", "encode_ms", "decode_ms", "client_ms", "gt_ms",
    "mean_server_ms", "mean_encode_ms", "mean_decode_ms", "mean_client_ms", "mean_gt_ms", "wall_s",
})


def is_timing_column(name: str) -> bool:
    """True for wall-clock columns (see :data:`TIMING_COLUMNS`; ``cli_*``/``srv_*`` ending in ``_ms``)."""
    return name in TIMING_COLUMNS or (name.startswith(("cli_", "srv_")) and name.endswith("_ms"))


def write_csv(path: str | Path, rows: Sequence[Row], columns: Sequence[str] | None = None) -> Path:
    """Write ``rows`` (union of keys, first-seen order unless ``columns`` given); NaN -> empty, bools -> 0/1, so
    :func:`read_csv` gives numbers back.  Written whole and atomically by :func:`splitrender.tabular.write_csv`."""
    p = Path(path)
    write_table(p, ({k: int(v) if isinstance(v, bool) else v for k, v in r.items()} for r in rows), columns)
    return p


def parse_value(text: str) -> Any:
    """CSV text -> int, float (empty -> NaN) or the string itself."""
    if text == "":
        return math.nan
    try:
        return int(text)
    except ValueError:
        pass
    try:
        return float(text)
    except ValueError:
        return text


def read_csv(path: str | Path) -> list[Row]:
    """Read a CSV written by :func:`write_csv`, parsing numbers."""
    with open(path, newline="") as f:
        return [{k: parse_value(v) for k, v in r.items()} for r in csv.DictReader(f)]


def column(rows: Iterable[Row], key: str) -> list[Any]:
    return [r.get(key, math.nan) for r in rows]


def fnum(v: Any) -> float:
    """A value as float (NaN for missing or non-numeric)."""
    try:
        return float(v)
    except (TypeError, ValueError):
        return math.nan


def network_columns(network: str) -> Row:
    """Modelled latency of a network string: one-way downlink delay/jitter and RTT (ms)."""
    p = parse_path(network)
    return {
        "net_delay_ms": float(p.downlink.delay_ms),
        "net_jitter_ms": float(p.downlink.jitter_ms),
        "net_rtt_ms": float(p.downlink.delay_ms + p.uplink.delay_ms),
    }


def run_row(summary: Row, cfg: RunConfig, extra: Row | None = None) -> Row:
    """One tidy ``runs.csv`` row: the run key, the summary, ``param_*`` and network columns."""
    row: Row = {"run": cfg.key()}
    row.update(summary)
    row.update({f"param_{k}": v for k, v in sorted(cfg.method_params.items())})
    row.update({"duration_s": cfg.duration_s if cfg.duration_s is not None else math.nan,
                "frame_ratio": cfg.server_fps / cfg.client_fps})
    try:
        row.update(network_columns(cfg.network))
    except Exception:  # noqa: BLE001 - a network the parser rejects cannot have run; keep the row
        log.warning("run %s: cannot parse network %r", cfg.key(), cfg.network)
    if extra:
        row.update(extra)
    return row


class ResultStore:
    """Per-run result folders under ``root/runs/<key>``; existing results are reused."""

    def __init__(self, root: str | Path) -> None:
        self.root = Path(root)
        self.runs_dir = self.root / "runs"

    def run_dir(self, key: str) -> Path:
        return self.runs_dir / key

    def has(self, cfg: RunConfig) -> bool:
        d = self.run_dir(cfg.key())
        return all((d / n).is_file() for n in ("summary.csv", "frames.csv", "config.toml"))

    def save(self, cfg: RunConfig, summary: Row, frames: Sequence[Row], updates: Sequence[Row]) -> Path:
        """Write one run's tables and its resolved config; the summary is written last (commit marker)."""
        d = self.run_dir(cfg.key())
        d.mkdir(parents=True, exist_ok=True)
        (d / "config.toml").write_text("[run]\n" + to_toml(cfg.to_dict()))
        write_csv(d / "frames.csv", frames)
        write_csv(d / "updates.csv", updates)
        write_csv(d / "summary.csv", [summary])
        return d

    def load_summary(self, cfg: RunConfig) -> Row:
        return read_csv(self.run_dir(cfg.key()) / "summary.csv")[0]

    def load_frames(self, key: str) -> list[Row]:
        return read_csv(self.run_dir(key) / "frames.csv")

    def load_updates(self, key: str) -> list[Row]:
        p = self.run_dir(key) / "updates.csv"
        return read_csv(p) if p.is_file() else []

    def write_tables(self, cfgs: Sequence[RunConfig], extra: dict[str, Row] | None = None) -> tuple[Path, Path]:
        """Write ``runs.csv`` and ``frames.csv`` for ``cfgs`` (in that order) from the run folders."""
        rows: list[Row] = []
        frames: list[Row] = []
        for cfg in cfgs:
            key = cfg.key()
            rows.append(run_row(self.load_summary(cfg), cfg, (extra or {}).get(key)))
            for fr in self.load_frames(key):
                frames.append({"run": key, "method": cfg.method, "network": cfg.network, "trace": cfg.trace,
                               "seed": cfg.seed, **fr})
        return write_csv(self.root / "runs.csv", rows), write_csv(self.root / "frames.csv", frames)


def load_results(root: str | Path) -> tuple[list[Row], list[Row]]:
    """``(runs, frames)`` of a results folder (``runs.csv``, else a demo's ``summary.csv``)."""
    r = Path(root)
    runs_p = r / "runs.csv"
    if not runs_p.is_file():
        runs_p = r / "summary.csv"
    if not runs_p.is_file():
        raise ConfigError(f"report: {r} has neither runs.csv nor summary.csv")
    frames_p = r / "frames.csv"
    return read_csv(runs_p), (read_csv(frames_p) if frames_p.is_file() else [])


__all__ = ["ResultStore", "Row", "TIMING_COLUMNS", "column", "fnum", "is_timing_column", "load_results", "summarise",
           "network_columns", "parse_value", "read_csv", "run_row", "write_csv"]


def summarise(runs: Sequence[Row]) -> list[Row]:
    """One row per method x network: means over traces (and seeds) of the runs' summaries."""
    groups: dict[tuple[str, str], list[Row]] = {}
    for r in runs:
        groups.setdefault((str(r["method"]), str(r["network"])), []).append(r)
    out = []
    for (m, net), rr in groups.items():
        row: Row = {"method": m, "network": net, "traces": "|".join(dict.fromkeys(str(r["trace"]) for r in rr)), "runs": len(rr)}
        keys = [k for k in rr[0] if k.startswith(("mean_", "p5_", "kbps_")) or k.endswith(("psnr_mse_db", "_content"))
                or k in ("flip_frames", "lost_frames", "net_delay_ms", "net_jitter_ms", "session_kb", "steady_kbps",
                         "content_frames", "frames_before_content")]
        for k in keys:
            vals = [fnum(r.get(k)) for r in rr if not math.isnan(fnum(r.get(k)))]
            row[k] = sum(vals) / len(vals) if vals else math.nan
        g = fnum(row.get("mean_gt_ms"))
        row["client_over_gt"] = fnum(row.get("mean_client_ms")) / g if g > 0 else math.nan
        out.append(row)
    return out
