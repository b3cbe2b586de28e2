"""Capacity traces that change over time, written in mahimahi's packet-delivery format.

A mahimahi trace lists, one per line, the millisecond of each delivery opportunity of
one 1500-byte packet (:data:`~.models.MAHIMAHI_MTU_BYTES`); the trace repeats with the
period of its last line.  A link spec's ``trace_path`` serves its bottleneck queue at
those opportunities, in virtual time and in the live relay alike.  Generators here:

- :func:`step_trace`: piecewise-constant capacity, e.g. 5 s at 20 Mbit/s then 5 s at 2;
- :func:`cellular_trace`: a cellular-like capacity with stated statistics: per
  ``slot_ms`` (50 ms) slot a log-normal rate whose log follows an AR(1) process with
  the given mean, coefficient of variation and correlation time, interrupted by outages
  (a two-state Markov chain with the given share of time and mean length) in which
  nothing is delivered.  The statistics hold over long traces; :func:`trace_stats`
  measures them on any trace, public ones included.

Public cellular traces (mahimahi's ``traces/`` folder: Verizon, T-Mobile, AT&T LTE
up- and downlinks) are read as they are: download one and give its path as a link's
``trace_path`` (network TOML) or ``--trace-file``; none is shipped with the project.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from splitrender.errors import NetworkConfigError

from .models import MAHIMAHI_MTU_BYTES

__all__ = ["CELLULAR_LIKE", "cellular_trace", "named_cellular_trace", "rate_series", "step_trace", "trace_stats",
           "write_mahimahi"]

_BITS_PER_OPP = MAHIMAHI_MTU_BYTES * 8


def _stamps_from_rates(rates_mbps: Sequence[float], slot_ms: int) -> np.ndarray:
    """Delivery opportunities for a rate per slot: spread evenly over each millisecond, fractions carried over."""
    out: list[int] = []
    carry = 0.0
    for k, r in enumerate(rates_mbps):
        if not (math.isfinite(r) and r >= 0):
            raise NetworkConfigError(f"capacity trace: slot {k} has rate {r!r} Mbit/s (must be finite and >= 0)")
        per_ms = r * 1e6 / 1000.0 / _BITS_PER_OPP
        for ms in range(k * slot_ms, (k + 1) * slot_ms):
            carry += per_ms
            n = int(carry)
            carry -= n
            out.extend([ms + 1] * n)      # mahimahi's first opportunity is at ms 1, not 0
    period = len(rates_mbps) * slot_ms
    if not out:
        raise NetworkConfigError("capacity trace: delivers nothing (every rate is 0)")
    if out[-1] != period:
        out.append(period)               # the last line sets the period: one opportunity at its end
    return np.asarray(out, np.int64)


def step_trace(steps: Sequence[tuple[float, float]], slot_ms: int = 10) -> np.ndarray:
    """Piecewise-constant capacity: ``steps`` is ``[(duration_s, mbps), ...]``; returns the trace's timestamps (ms)."""
    if not steps:
        raise NetworkConfigError("step trace: no steps")
    rates: list[float] = []
    for i, (dur, mbps) in enumerate(steps):
        if not (math.isfinite(dur) and dur > 0):
            raise NetworkConfigError(f"step trace: step {i} lasts {dur!r} s (must be > 0)")
        rates += [float(mbps)] * max(1, int(round(dur * 1000 / slot_ms)))
    return _stamps_from_rates(rates, slot_ms)


def cellular_trace(duration_s: float, mean_mbps: float = 8.0, cv: float = 0.5, corr_time_s: float = 1.0,
                   outage_share: float = 0.02, outage_mean_s: float = 0.3, slot_ms: int = 50, seed: int = 0) -> np.ndarray:
    """A cellular-like capacity trace (module docstring); ``cv`` is the coefficient of variation of the rate outside
    outages, ``corr_time_s`` the e-folding time of the log-rate's autocorrelation.  Deterministic for a seed."""
    for name, v, ok in (("duration_s", duration_s, duration_s > 0), ("mean_mbps", mean_mbps, mean_mbps > 0),
                        ("cv", cv, cv >= 0), ("corr_time_s", corr_time_s, corr_time_s > 0),
                        ("outage_share", outage_share, 0 <= outage_share < 1), ("outage_mean_s", outage_mean_s, outage_mean_s > 0)):
        if not (math.isfinite(v) and ok):
            raise NetworkConfigError(f"cellular trace: {name} = {v!r} is out of range")
    rng = np.random.default_rng(seed)
    n = max(1, int(round(duration_s * 1000 / slot_ms)))
    slot_s = slot_ms / 1000.0
    rho = math.exp(-slot_s / corr_time_s)
    sigma = math.sqrt(math.log(1 + cv * cv))
    z = np.empty(n)
    z[0] = rng.standard_normal()
    innov = rng.standard_normal(n) * math.sqrt(1 - rho * rho)
    for k in range(1, n):
        z[k] = rho * z[k - 1] + innov[k]
    rates = mean_mbps * np.exp(sigma * z - sigma * sigma / 2)
    if outage_share > 0:
        p_end = min(1.0, slot_s / outage_mean_s)                       # leave an outage
        p_start = min(1.0, p_end * outage_share / (1 - outage_share))  # enter one (stationary share = outage_share)
        down = False
        for k in range(n):
            down = rng.random() < (1 - p_end if down else p_start)
            if down:
                rates[k] = 0.0
        if not rates.any():
            rates[-1] = mean_mbps
    return _stamps_from_rates(rates.tolist(), slot_ms)


CELLULAR_LIKE: dict[str, dict[str, Any]] = {
    "cellular": {"mean_mbps": 4.0, "cv": 0.5},
    "cellular8": {"mean_mbps": 8.0, "cv": 0.5},
    "harsh": {"mean_mbps": 4.0, "cv": 0.8, "corr_time_s": 0.3, "outage_share": 0.08},
}
"""The project's named cellular-like traces (:func:`cellular_trace`'s arguments besides the duration and seed), shared
by the link study and the adaptation benchmarks: ``cellular``, 4 Mbit/s on average, where the 320x180 methods meet the
link often; ``cellular8``, 8 Mbit/s, where ``sas`` and ``tss`` meet it only in its dips; ``harsh``, the parameters that
land inside mahimahi's public LTE/UMTS downlinks (docs/experiments.md)."""


def named_cellular_trace(name: str, duration_s: float, seed: int = 0) -> np.ndarray:
    """The named trace of :data:`CELLULAR_LIKE` over ``duration_s`` at ``seed`` (its timestamps, ms)."""
    try:
        params = CELLULAR_LIKE[name]
    except KeyError:
        raise NetworkConfigError(f"cellular trace: no trace named {name!r} (known: {', '.join(CELLULAR_LIKE)})") from None
    return cellular_trace(duration_s, seed=seed, **params)


def rate_series(stamps_ms: np.ndarray, slot_ms: int = 100) -> np.ndarray:
    """Capacity per ``slot_ms`` slot over one period of a trace, Mbit/s."""
    stamps = np.asarray(stamps_ms, np.int64)
    period = int(stamps[-1])
    n = max(1, math.ceil(period / slot_ms))
    # a stamp t serves slot (t - 1) // slot_ms, and t = 0 (public traces start with it) the first
    counts = np.bincount(np.clip((stamps - 1) // slot_ms, 0, n - 1), minlength=n)
    return counts * _BITS_PER_OPP / (slot_ms / 1000.0) / 1e6


def trace_stats(stamps_ms: np.ndarray, slot_ms: int = 50) -> dict[str, float]:
    """Mean capacity (Mbit/s), coefficient of variation outside outages, share of slots with nothing delivered, and
    the lag-1 autocorrelation of the rate outside outages, over ``slot_ms`` slots."""
    r = rate_series(stamps_ms, slot_ms)
    up = r[r > 0]
    ac = float(np.corrcoef(r[:-1], r[1:])[0, 1]) if r.size > 2 and r[:-1].std() > 0 and r[1:].std() > 0 else math.nan
    return {"mean_mbps": float(r.mean()), "cv": float(up.std() / up.mean()) if up.size else math.nan,
            "outage_share": float((r == 0).mean()), "lag1_corr": ac, "period_s": float(stamps_ms[-1]) / 1000.0}


def write_mahimahi(stamps_ms: np.ndarray, path: str | Path) -> Path:
    """Write a trace (one millisecond timestamp per line) that :func:`~.models.load_mahimahi_trace` reads back."""
    p = Path(path)
    p.write_text("".join(f"{int(s)}\n" for s in stamps_ms), encoding="ascii")
    return p
