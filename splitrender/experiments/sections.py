"""A report section: what a study hands to the report writer; where studies are found and their sections kept.

Studies (``splitrender/experiments/studies/*.py``) each expose
``run(out_dir: Path, quick: bool) -> Section``; the report embeds every section's
Markdown text, figures (PNG/SVG paths relative to the report's folder or absolute)
and tables (CSV paths) in order.
"""

from __future__ import annotations

import json
import logging
import pkgutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from . import studies

log = logging.getLogger(__name__)


@dataclass
class Section:
    title: str
    text_md: str = ""
    figures: list[Path] = field(default_factory=list)
    tables: list[Path] = field(default_factory=list)
    elapsed_s: float | None = None
    """How long the study took (wall clock), when it ran as one."""

    def to_dict(self) -> dict[str, object]:
        return {"title": self.title, "text_md": self.text_md, "figures": [str(f) for f in self.figures],
                "tables": [str(t) for t in self.tables], "elapsed_s": self.elapsed_s}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "Section":
        el = d.get("elapsed_s")
        return cls(str(d["title"]), str(d.get("text_md", "")), [Path(str(f)) for f in d.get("figures") or []],
                   [Path(str(t)) for t in d.get("tables") or []], float(el) if isinstance(el, (int, float)) else None)


def discover_studies() -> list[str]:
    """Names of the modules in :mod:`splitrender.experiments.studies` (sorted)."""
    return sorted(m.name for m in pkgutil.iter_modules(studies.__path__) if not m.name.startswith("_"))


STUDY_SECTION_FILE = "section.json"


def save_study_section(out: Path, name: str, sec: Section) -> Path:
    """``out/studies/<name>/section.json``: the study's section (paths relative to ``out``) and its time, for the
    report of ``out`` whichever command ran the study."""
    p = out / "studies" / name / STUDY_SECTION_FILE
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_text(json.dumps(sec.to_dict(), indent=1))
    return p


def load_study_sections(out: Path) -> list[Section]:
    """Every study section saved under ``out/studies`` (in the studies' order, unknown names after)."""
    order = {n: i for i, n in enumerate(discover_studies())}
    found = sorted((p for p in (out / "studies").glob(f"*/{STUDY_SECTION_FILE}")),
                   key=lambda p: (order.get(p.parent.name, len(order)), p.parent.name))
    out_secs = []
    for p in found:
        try:
            out_secs.append(Section.from_dict(json.loads(p.read_text())))
        except (ValueError, KeyError, TypeError) as exc:
            log.warning("%s: not a study section (%s); left out of the report", p, exc)
    return out_secs
