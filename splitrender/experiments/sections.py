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
