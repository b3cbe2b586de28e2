"""Results I/O: per-run folders keyed by ``RunConfig.key()`` and the tidy tables.

Layout of a results folder (sweep or demo)::

    DIR/runs/<key>/config.toml     the full resolved RunConfig
    DIR/runs/<key>/summary.csv     one row (RunResult.summary)
    DIR/runs/<key>/frames.csv      one row per displayed frame
    DIR/runs/<key>/updates.csv     one row per server frame
    DIR/runs/<key>/code.json       the digest of the method's code that made it, and the commit
    DIR/runs.csv                   one row per run: summary + ``param_*`` + network columns
    DIR/frames.csv                 one row per displayed frame of every run, with ``run`` (the key)

Tables are lists of dicts (no pandas dependency); :func:`read_csv` turns numeric
text back into floats/ints so charts and tests can use the values directly.
"""

from __future__ import annotations

import csv
import functools
import hashlib
import json
import logging
import math
import re
import subprocess
import sys
from pathlib import Path
from typing import Any, Iterable, Sequence

from ..errors import ConfigError
from ..netsim import parse_path
from ..sim.config import RunConfig
from ..tabular import write_csv as write_table

log = logging.getLogger(__name__)

Row = dict[str, Any]

#: Columns that are wall-clock measurements on this machine: they differ between two
#: executions of the same config; everything else in a run's tables is deterministic.
TIMING_COLUMNS = frozenset({
    "server_ms", "shared_ms", "encode_ms", "decode_ms", "client_ms", "gt_ms",
    "mean_server_ms", "mean_shared_server_ms", "mean_encode_ms", "mean_decode_ms", "mean_client_ms", "mean_gt_ms",
    "wall_s",
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


_METHODS_DIR = Path(__file__).resolve().parents[1] / "methods"
_SIBLING = re.compile(r"^\s*from \.\.(\w+)", re.M)


@functools.lru_cache(maxsize=None)
def method_digest(method: str) -> str:
    """A digest (16 hex digits) of the source that makes ``method``'s halves (:func:`source_digest` of the package
    its config comes from; for a method registered from outside ``splitrender/methods``, its module's file).  A
    stored run made by other code of its method is stale (:meth:`ResultStore.has`).  Code outside the methods (the
    pipeline, codecs, renderer) is not in it: a change there leaves stored runs standing."""
    from ..methods import get_method

    src = Path(str(sys.modules[get_method(method).config.__module__].__file__)).resolve()
    return source_digest(src, _METHODS_DIR)


def source_digest(src: Path, methods_dir: Path) -> str:
    """The digest of a method whose config is defined in ``src``: where ``src`` lies in a package directly under
    ``methods_dir``, every file of that package (shaders included) and of the method packages its modules import from
    (``from ..sas import``: tss's geometry coding is sas's), else ``src`` alone; and the methods' shared ``base.py``
    and ``shaders/``.  Paths enter relative to ``methods_dir``'s parent, so two checkouts of one commit agree."""
    pkg = src.parent if src.parent != methods_dir and src.parent.parent == methods_dir else None
    files: set[Path] = set() if pkg is not None else {src}
    todo, seen = [pkg] if pkg is not None else [], set()
    while todo:
        d = todo.pop()
        if d in seen or not d.is_dir():
            continue
        seen.add(d)
        for f in d.rglob("*"):
            if f.is_file() and "__pycache__" not in f.parts:
                files.add(f)
                if f.suffix == ".py":
                    todo += [methods_dir / m for m in _SIBLING.findall(f.read_text(errors="replace"))]
    files |= {f for f in (methods_dir / "base.py", *(methods_dir / "shaders").rglob("*")) if f.is_file()}
    h = hashlib.sha256()
    for f in sorted(files):
        name = f.relative_to(methods_dir.parent) if f.is_relative_to(methods_dir.parent) else f
        h.update(str(name).encode() + b"\0" + f.read_bytes() + b"\0")
    return h.hexdigest()[:16]


CODE_FILE = "code.json"
"""Beside a stored run: the digest of its method's code (:func:`method_digest`) and the commit, where known."""


@functools.lru_cache(maxsize=1)
def _commit() -> str:
    """The source checkout's commit (with ``+`` when its tracked files differ from it), or "" outside one."""
    root = _METHODS_DIR.parents[1]
    try:
        sha = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=root, capture_output=True, text=True,
                             timeout=10).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=root,
                               capture_output=True, text=True, timeout=10).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return ""
    return sha + ("+" if sha and dirty else "")


class ResultStore:
    """Per-run result folders under ``root/runs/<key>``; existing results are reused while their method's code is the
    code that made them (:func:`method_digest`, kept in :data:`CODE_FILE`): a run made by other code of its method,
    or by a version of this store that kept no digest, runs again."""

    def __init__(self, root: str | Path) -> None:
        self.root = Path(root)
        self.runs_dir = self.root / "runs"

    def run_dir(self, key: str) -> Path:
        return self.runs_dir / key

    def has(self, cfg: RunConfig) -> bool:
        """The run's tables are here, made by its method's present code."""
        d = self.run_dir(cfg.key())
        if not all((d / n).is_file() for n in ("summary.csv", "frames.csv", "config.toml")):
            return False
        try:
            made = json.loads((d / CODE_FILE).read_text()).get("method_digest")
        except (OSError, ValueError, AttributeError):
            made = None
        if made != method_digest(cfg.method):
            log.info("run %s (%s): stored by %s of its method's code, now %s: it runs again", cfg.key(), cfg.method,
                     "another version" if made else "a store that kept no digest", method_digest(cfg.method))
            return False
        return True

    def save(self, cfg: RunConfig, summary: Row, frames: Sequence[Row], updates: Sequence[Row]) -> Path:
        """Write one run's tables and its resolved config; the summary is written last (commit marker)."""
        d = self.run_dir(cfg.key())
        d.mkdir(parents=True, exist_ok=True)
        (d / "config.toml").write_text(cfg.toml())
        write_csv(d / "frames.csv", frames)
        write_csv(d / "updates.csv", updates)
        (d / CODE_FILE).write_text(json.dumps({"method": cfg.method, "method_digest": method_digest(cfg.method),
                                               "commit": _commit()}) + "\n")
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
