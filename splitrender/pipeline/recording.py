"""The one recording writer every front door uses (issue 47: "rows and recordings written once").

A client's recording is a folder:

- ``recording.json``: the manifest (method, scene, trace, display, the client's settings), ``complete: false`` while
  the session runs and once more, with the error, if it ends early;
- ``frames.jsonl``: the displayed rows appended as they come (:data:`JOURNAL`), flushed every
  :data:`JOURNAL_FLUSH_S`, so that a killed client leaves what it showed; replaced by ``frames.csv`` at the end;
- ``counters.json``: the session's counters;
- ``images/``: displayed images where asked for (:func:`save_image`).

:class:`ClientRecording` writes it for the headless client (as the session goes) and the browser front door (whole,
from the page's upload), both with the one manifest of :func:`manifest`; the virtual-time runner writes the same
``frames.csv`` beside its scored tables (:func:`write_run`).  A server keeps per session the rows its core records
(``updates.csv``, ``feedback.csv``: :meth:`~.session.ServerSession.rows_to_write`) and its counters (``counters.csv``)
with :class:`SessionLogs`, in the TCP server and the browser front door alike."""

from __future__ import annotations

import json
import math
import time
from collections import defaultdict, deque
from pathlib import Path
from typing import IO, Any, Iterable, Iterator, Sequence

import numpy as np

from .rows import FEEDBACK_COLUMNS, live_frame_row
from ..tabular import CsvAppender, atomic_file, atomic_write_bytes, write_csv, write_csv_passes

JOURNAL = "frames.jsonl"
"""Rows appended while the session runs; replaced by frames.csv at the end, left behind by a killed client."""
JOURNAL_FLUSH_S = 0.5
"""How often the journal is flushed to the operating system (s)."""
ROWS_KEPT = 1024
"""Rows of each kind a server session keeps in memory (:attr:`SessionLogs.recent`: the newest; the row logs on disk
have them all), and a client recording by default (:attr:`ClientRecording.recent`)."""


def _json(obj: Any) -> bytes:
    return json.dumps(obj, indent=2, default=str).encode()


class MetricsLog:
    """A live session's ``metrics`` log line, in every live front door (the server's two and the headless client):
    ``metrics session=<id> name=value ...`` on ``log`` at most every ``interval_s`` (0: never), the first
    ``interval_s`` after the session's start."""

    def __init__(self, log: Any, session_id: str, interval_s: float) -> None:
        self.log, self.session_id, self.interval_s = log, session_id, interval_s
        self._next = time.monotonic() + interval_s

    def due(self) -> bool:
        """Whether a line is due now (its clock then restarts): :meth:`write` it."""
        if self.interval_s <= 0 or time.monotonic() < self._next:
            return False
        self._next = time.monotonic() + self.interval_s
        return True

    def write(self, counters: dict[str, Any]) -> None:
        """One ``metrics`` line of ``counters``."""
        self.log.info("metrics session=%s %s", self.session_id, " ".join(f"{k}={v}" for k, v in counters.items()))


def manifest(session_id: str, method: str, params: dict[str, Any], scene: str, fov_y_deg: float, server_fps: float,
             trace: str, width: int, height: int, display_hz: float, tracker_hz: float, duration_s: float,
             images: bool, client: dict[str, Any], **extra: Any) -> dict[str, Any]:
    """A client recording's ``recording.json``, the same keys from every client front door: the session, its method
    and method parameters, what :func:`splitrender.client.score.score_recording` needs to render the ground truth
    (scene, field of view, display size) and to summarise (trace, rates, duration; ``images``: whether displayed
    images were kept), the client's own settings (``client``), and ``extra`` (``complete``, ``network``, ``error``)."""
    return {"session_id": session_id, "method": method, "params": params, "scene": scene, "fov_y_deg": fov_y_deg,
            "server_fps": server_fps, "trace": trace, "width": width, "height": height, "display_hz": display_hz,
            "tracker_hz": tracker_hz, "duration_s": duration_s, "images": images, "client": client, **extra}


class ClientRecording:
    """A client's recording folder ``out_dir`` (module docstring; None: nothing written, the rows only counted and
    kept).  :meth:`start`, then :meth:`append` per displayed row, then :meth:`finish`; or :meth:`finish` alone with
    every row (a recording uploaded whole).  The newest ``rows_kept`` rows stay in :attr:`recent` (the journal and
    ``frames.csv`` have them all)."""

    def __init__(self, out_dir: Path | None, rows_kept: int = ROWS_KEPT) -> None:
        self.dir = None if out_dir is None else Path(out_dir)
        self._journal: IO[str] | None = None
        self._flushed = 0.0
        self.rows = 0
        """The rows appended so far."""
        self.recent: deque[dict[str, Any]] = deque(maxlen=rows_kept)

    @property
    def started(self) -> bool:
        return self._journal is not None

    def start(self, manifest: dict[str, Any]) -> None:
        """Write the manifest (``complete: false``), drop what an earlier session left, open the journal."""
        if self.dir is None:
            return
        self.dir.mkdir(parents=True, exist_ok=True)
        for stale in ("frames.csv", "summary.csv", "counters.json"):
            (self.dir / stale).unlink(missing_ok=True)
        atomic_write_bytes(self.dir / "recording.json", _json({**manifest, "complete": False}))
        self._journal = open(self.dir / JOURNAL, "w", buffering=1 << 16)
        self._flushed = time.monotonic()

    def append(self, row: dict[str, Any]) -> None:
        """One displayed row: counted, kept in :attr:`recent`, and into the journal once :meth:`start` opened it."""
        self.recent.append(row)
        self.rows += 1
        if self._journal is None:
            return
        self._journal.write(json.dumps(row, default=float) + "\n")
        now = time.monotonic()
        if now - self._flushed >= JOURNAL_FLUSH_S:
            self._journal.flush()
            self._flushed = now

    def tick(self, tick: int, trace_t: float, scene_t: float, pose: Any, shown: Any, displayed_us: int,
             client_ms: float = math.nan, **columns: Any) -> dict[str, Any]:
        """A display tick's row (:func:`~.rows.live_frame_row`, ``shown`` the update shown or None for the black
        background; numbered by the rows so far) with ``columns`` after it: appended, and returned."""
        row = {**live_frame_row(self.rows, tick, trace_t, scene_t, pose, shown, displayed_us, client_ms), **columns}
        self.append(row)
        return row

    @staticmethod
    def ended(manifest: dict[str, Any], exc: BaseException | None = None) -> dict[str, Any]:
        """The final manifest of a session that ended: ``complete``, or (``exc``: a broken session, whose recording
        keeps what was recorded) incomplete, with the ``error`` that ended it."""
        if exc is None:
            return {**manifest, "complete": True}
        return {**manifest, "complete": False, "error": f"{type(exc).__name__}: {exc}"}

    def finish(self, manifest: dict[str, Any], counters: dict[str, Any],
               rows: Sequence[dict[str, Any]] | None = None) -> None:
        """``frames.csv`` (from the journal, every row, or from ``rows`` when there is none), ``counters.json`` and the
        final manifest; the journal goes once they are written."""
        if self.dir is None:
            return
        self.dir.mkdir(parents=True, exist_ok=True)
        if self._journal is not None:
            self._journal.close()
            self._journal = None
            journal_to_csv(self.dir / JOURNAL, self.dir / "frames.csv")
        else:
            write_csv(self.dir / "frames.csv", list(rows or []))
        atomic_write_bytes(self.dir / "recording.json", _json(manifest))
        atomic_write_bytes(self.dir / "counters.json", _json(counters))
        (self.dir / JOURNAL).unlink(missing_ok=True)


def write_run(out_dir: Path, frames: list[dict[str, Any]], updates: list[dict[str, Any]],
              summaries: list[dict[str, Any]], config_toml: str,
              images: Sequence[tuple[int, np.ndarray, np.ndarray]] = ()) -> Path:
    """A virtual-time run's folder: ``frames.csv`` (the display rows, the columns a client recording's has, scored),
    ``updates.csv`` (the server's rows), ``summary.csv`` (a row per client), ``config.toml`` and, where kept, each
    ``images/frameNNNNN_client_vs_truth.png`` (the client's frame beside the ground truth)."""
    d = Path(out_dir)
    d.mkdir(parents=True, exist_ok=True)
    write_csv(d / "frames.csv", frames)
    write_csv(d / "updates.csv", updates)
    write_csv(d / "summary.csv", summaries)
    (d / "config.toml").write_text(config_toml)
    if images:
        from PIL import Image   # only runs that keep images need it

        (d / "images").mkdir(exist_ok=True)
        for frame, shown, truth in images:
            Image.fromarray(np.concatenate([shown, truth], axis=1)).save(d / "images" / f"frame{frame:05d}_client_vs_truth.png")
    return d


def save_image(out_dir: Path, index: int, color: np.ndarray, holes: np.ndarray | None) -> None:
    """A displayed image (and its holes) as ``images/<index>.npz``; a client killed mid-write leaves no truncated
    file."""
    d = Path(out_dir) / "images"
    d.mkdir(parents=True, exist_ok=True)
    arrays: dict[str, np.ndarray] = {"color": color}
    if holes is not None:
        arrays["holes"] = holes
    with atomic_file(d / f"{index:06d}.npz", "wb") as f:
        np.savez_compressed(f, **arrays)  # type: ignore[arg-type]


def iter_journal(path: Path) -> Iterator[dict[str, Any]]:
    """The rows of a ``frames.jsonl`` (one JSON object per line, ``null`` read as NaN), one at a time; a torn last
    line (a client killed mid-write) ends them."""
    with open(path) as f:
        for line in f:
            try:
                row = json.loads(line)
            except json.JSONDecodeError:
                return
            if isinstance(row, dict):
                yield {k: (math.nan if v is None else v) for k, v in row.items()}


def journal_to_csv(journal: Path, out: Path) -> int:
    """``frames.jsonl`` as ``frames.csv`` (every key a column, in order of first appearance), in two passes over
    the file so that memory stays flat whatever its length.  Returns the rows written."""
    return write_csv_passes(out, lambda: iter_journal(journal))


class SessionLogs:
    """A server's records of one session under ``out_dir`` (None: none kept): row logs appended as they come,
    ``<name>.csv`` each (opened with its first row; columns fixed then, from ``columns`` or that row's keys), and
    ``counters.csv`` written once at :meth:`close`.  The newest :data:`ROWS_KEPT` rows of each log stay in
    :attr:`recent`, with ``out_dir`` or without."""

    def __init__(self, out_dir: Path | None) -> None:
        self.dir = None if out_dir is None else Path(out_dir)
        self._logs: dict[str, CsvAppender] = {}
        self.recent: dict[str, deque[dict[str, Any]]] = defaultdict(lambda: deque(maxlen=ROWS_KEPT))

    def append(self, name: str, row: dict[str, Any], columns: Sequence[str] | None = None) -> None:
        self.recent[name].append(row)
        if self.dir is None:
            return
        log = self._logs.get(name)
        if log is None:
            self.dir.mkdir(parents=True, exist_ok=True)
            log = self._logs[name] = CsvAppender(self.dir / f"{name}.csv", list(columns or row))
        log.append(row)

    def write(self, rows: Iterable[tuple[str, dict[str, Any]]]) -> None:
        """:meth:`append` each (name, row) a server core recorded (:meth:`~.session.ServerSession.rows_to_write`),
        ``feedback`` rows under their fixed columns (a Feedback may echo fewer timings)."""
        for name, row in rows:
            self.append(name, row, FEEDBACK_COLUMNS if name == "feedback" else None)

    def rows(self, name: str) -> int:
        """How many rows ``<name>.csv`` has taken."""
        log = self._logs.get(name)
        return 0 if log is None else log.rows

    def close(self, counters: dict[str, Any] | None = None) -> None:
        """Close the row logs and write ``counters.csv`` (only where a row was logged: a session that sent
        nothing leaves no folder)."""
        for log in self._logs.values():
            log.close()
        if self.dir is not None and self._logs and counters is not None:
            write_csv(self.dir / "counters.csv", [counters])
