"""A report section: what a study hands to the report writer.

Studies (``splitrender/experiments/studies/*.py``) each expose
``run(out_dir: Path, quick: bool) -> Section``; the report embeds every section's
Markdown text, figures (PNG/SVG paths relative to the report's folder or absolute)
and tables (CSV paths) in order.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path


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
    def from_dict(cls, d: dict[str, object]) -> "Section":
        el = d.get("elapsed_s")
        return cls(str(d["title"]), str(d.get("text_md", "")), [Path(str(f)) for f in d.get("figures", []) or []],  # type: ignore[union-attr]
                   [Path(str(t)) for t in d.get("tables", []) or []],  # type: ignore[union-attr]
                   float(el) if isinstance(el, (int, float)) else None)
