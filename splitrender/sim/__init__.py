"""Virtual-time simulation: the deterministic runner and its configuration."""

from .config import RunConfig
from .runner import RunResult, VirtualTimeRun, run

__all__ = ["RunConfig", "RunResult", "VirtualTimeRun", "run"]
