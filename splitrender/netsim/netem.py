"""netem-style strings: parse them into a :class:`LinkSpec` and render one back.

Grammar (the arguments after ``tc qdisc ... netem``; a leading ``netem`` is allowed)::

    delay TIME [JITTER [CORRELATION%]] [distribution uniform|normal|pareto|paretonormal]
    loss [random] PERCENT [CORRELATION%]
    loss gemodel P% [R% [1-H% [1-K%]]]
    duplicate PERCENT [CORRELATION%]
    corrupt PERCENT [CORRELATION%]
    reorder PERCENT [CORRELATION%] [gap N]
    rate RATE
    limit PACKETS
    trace PATH              (splitrender extension: mahimahi trace; not for tc)
    spike EXTRA START DUR   (splitrender extension: EXTRA delay for packets sent in
                            [START, START+DUR), e.g. ``spike 250ms 2s 1s``; not for tc)

Times need a unit: ``s``/``sec``/``ms``/``msec``/``us``/``usec`` (tc reads a bare
number as microseconds, a classic mistake, so it is refused here).  Rates follow tc:
``bit``/``kbit``/``mbit``/``gbit``/``tbit`` are bits per second (powers of 1000),
``bps``/``kbps``/``mbps``/``gbps`` are **bytes** per second.  Percentages need ``%``.

``distribution uniform`` is accepted for readability but is what netem does without
a distribution table, and real ``tc`` has no ``uniform`` table, so :func:`to_netem`
never writes it.  Errors are :class:`NetworkConfigError` naming the token and its
1-based position, e.g. ``netem: 'fast' is not a time (expected e.g. 20ms) at token 2``.
"""

from __future__ import annotations

import math
import re
from typing import Any

from splitrender.errors import NetworkConfigError
from splitrender.netsim.models import DISTRIBUTIONS, GilbertElliott, LinkSpec

_NUMBER = r"([0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE]([-+]?[0-9]{1,3}))?"
_TIME_RE = re.compile(_NUMBER + r"(s|sec|secs|ms|msec|msecs|us|usec|usecs)", re.IGNORECASE)
_PERCENT_RE = re.compile(_NUMBER + r"%")
_RATE_RE = re.compile(_NUMBER + r"(bit|kbit|mbit|gbit|tbit|bps|kbps|mbps|gbps|tbps)", re.IGNORECASE)
_INT_RE = re.compile(r"[0-9]{1,9}")

_TIME_TO_MS = {
    "s": 1000.0, "sec": 1000.0, "secs": 1000.0,
    "ms": 1.0, "msec": 1.0, "msecs": 1.0,
    "us": 0.001, "usec": 0.001, "usecs": 0.001,
}
_RATE_TO_BPS = {
    "bit": 1.0, "kbit": 1e3, "mbit": 1e6, "gbit": 1e9, "tbit": 1e12,
    "bps": 8.0, "kbps": 8e3, "mbps": 8e6, "gbps": 8e9, "tbps": 8e12,
}
KEYWORDS: tuple[str, ...] = (
    "corrupt", "delay", "distribution", "duplicate", "gap", "limit", "loss", "rate",
    "reorder", "spike", "trace",
)


def _number(m: re.Match[str]) -> float:
    text = m.group(1) + (f"e{m.group(2)}" if m.group(2) else "")
    return float(text)


class _Tokens:
    def __init__(self, text: str) -> None:
        self.toks = text.split()
        self.i = 0

    def error(self, message: str, pos: int | None = None) -> NetworkConfigError:
        return NetworkConfigError(f"netem: {message} at token {(self.i if pos is None else pos) + 1}")

    def peek(self) -> str | None:
        return self.toks[self.i] if self.i < len(self.toks) else None

    def take(self, what: str, after: str) -> str:
        tok = self.peek()
        if tok is None:
            raise self.error(f"missing {what} after {after!r}")
        self.i += 1
        return tok

    def _value(self, regex: re.Pattern[str], what: str, example: str, tok: str) -> re.Match[str]:
        m = regex.fullmatch(tok)
        if m is None:
            raise self.error(f"{tok!r} is not a {what} (expected e.g. {example})", self.i - 1)
        return m

    def time_ms(self, after: str) -> float:
        tok = self.take("time", after)
        m = self._value(_TIME_RE, "time", "20ms", tok)
        value = _number(m) * _TIME_TO_MS[m.group(3).lower()]
        return self._finite(value, tok)

    def percent(self, after: str) -> float:
        tok = self.take("percentage", after)
        value = self._finite(_number(self._value(_PERCENT_RE, "percentage", "1%", tok)), tok)
        if value > 100.0:
            raise self.error(f"{tok!r} is out of range 0..100%", self.i - 1)
        return value

    def rate_bps(self, after: str) -> float:
        tok = self.take("rate", after)
        m = self._value(_RATE_RE, "rate", "20mbit", tok)
        value = self._finite(_number(m) * _RATE_TO_BPS[m.group(3).lower()], tok)
        if value <= 0:
            raise self.error(f"{tok!r} is not a positive rate", self.i - 1)
        return value

    def count(self, what: str, after: str) -> int:
        tok = self.take(what, after)
        if _INT_RE.fullmatch(tok) is None:
            raise self.error(f"{tok!r} is not a {what} (expected e.g. 1000)", self.i - 1)
        return int(tok)

    def _finite(self, value: float, tok: str) -> float:
        if not math.isfinite(value):
            raise self.error(f"{tok!r} is out of range", self.i - 1)
        return value

    def next_is(self, regex: re.Pattern[str]) -> bool:
        tok = self.peek()
        return tok is not None and regex.fullmatch(tok) is not None


def parse_netem(text: str) -> LinkSpec:
    """Parse netem arguments (see module docstring) into a :class:`LinkSpec`."""
    if not isinstance(text, str):
        raise NetworkConfigError(f"netem: expected a string, got {type(text).__name__}")
    t = _Tokens(text)
    if t.peek() == "netem":
        t.i += 1
    fields: dict[str, Any] = {}
    seen: set[str] = set()
    while (kw := t.peek()) is not None:
        pos = t.i
        t.i += 1
        if kw not in KEYWORDS:
            raise t.error(
                f"unknown keyword {kw!r} (expected one of: {', '.join(KEYWORDS)})", pos
            )
        if kw in seen:
            raise t.error(f"{kw!r} given twice", pos)
        seen.add(kw)
        if kw == "delay":
            fields["delay_ms"] = t.time_ms("delay")
            if t.next_is(_TIME_RE):
                fields["jitter_ms"] = t.time_ms("delay")
                if t.next_is(_PERCENT_RE):
                    fields["delay_correlation_pct"] = t.percent("delay")
        elif kw == "distribution":
            tok = t.take("distribution name", "distribution")
            if tok not in DISTRIBUTIONS:
                raise t.error(
                    f"{tok!r} is not a distribution (expected one of: "
                    f"{', '.join(sorted(DISTRIBUTIONS))})",
                    t.i - 1,
                )
            fields["distribution"] = tok
        elif kw == "loss":
            mode = t.peek()
            if mode in ("random", "gemodel", "state"):
                t.i += 1
            if mode == "state":
                raise t.error("'loss state' (4-state Markov) is not supported; use gemodel", t.i - 1)
            if mode == "gemodel":
                p = t.percent("gemodel")
                more: list[float] = []
                while len(more) < 3 and t.next_is(_PERCENT_RE):
                    more.append(t.percent("gemodel"))
                names = ("r_pct", "bad_loss_pct", "good_loss_pct")
                fields["gemodel"] = GilbertElliott(p, **dict(zip(names, more)))
            else:
                fields["loss_pct"] = t.percent("loss")
                if t.next_is(_PERCENT_RE):
                    fields["loss_correlation_pct"] = t.percent("loss")
        elif kw in ("duplicate", "corrupt", "reorder"):
            fields[f"{kw}_pct"] = t.percent(kw)
            if t.next_is(_PERCENT_RE):
                fields[f"{kw}_correlation_pct"] = t.percent(kw)
            if kw == "reorder" and t.peek() == "gap":
                if "gap" in seen:
                    raise t.error("'gap' given twice", t.i)
                seen.add("gap")
                t.i += 1
                fields["reorder_gap"] = t.count("gap distance", "gap")
        elif kw == "gap":
            fields["reorder_gap"] = t.count("gap distance", "gap")
        elif kw == "rate":
            fields["rate_bps"] = t.rate_bps("rate")
        elif kw == "limit":
            fields["limit_packets"] = t.count("packet count", "limit")
        elif kw == "trace":
            fields["trace_path"] = t.take("trace file", "trace")
        elif kw == "spike":
            fields["spike_ms"] = t.time_ms("spike")
            fields["spike_start_s"] = t.time_ms("spike delay") / 1000.0
            fields["spike_duration_s"] = t.time_ms("spike start") / 1000.0
    try:
        return LinkSpec(**fields)
    except NetworkConfigError as exc:
        raise NetworkConfigError(f"netem: {exc}") from None


def _fmt(value: float) -> str:
    """Shortest text that parses back to exactly ``value``."""
    if value == int(value) and abs(value) < 1e15:
        return str(int(value))
    return repr(float(value))


def _fmt_rate(bps: float) -> str:
    for unit, scale in (("gbit", 1e9), ("mbit", 1e6), ("kbit", 1e3)):
        q = bps / scale
        if q == int(q) and q >= 1 and q * scale == bps:
            return f"{int(q)}{unit}"
    return f"{_fmt(bps)}bit"


def to_netem(spec: LinkSpec) -> str:
    """Render ``spec`` as ``tc qdisc ... netem`` arguments (``parse_netem`` inverts it).

    ``keep_order`` has no netem equivalent (netem reorders with jitter) and is not
    written; a ``trace_path`` cannot be expressed for tc and raises
    :class:`NetworkConfigError`.  An ideal spec renders as ``""``.
    """
    if spec.trace_path is not None:
        raise NetworkConfigError("netem: a mahimahi trace (trace_path) cannot be expressed for tc")
    if spec.spike_ms:
        raise NetworkConfigError("netem: a timed latency spike (spike_ms) cannot be expressed in one tc command")
    d = LinkSpec()
    parts: list[str] = []
    if spec.delay_ms or spec.jitter_ms or spec.delay_correlation_pct or (
        spec.distribution != d.distribution
    ):
        parts += ["delay", f"{_fmt(spec.delay_ms)}ms"]
        if spec.jitter_ms or spec.delay_correlation_pct:
            parts.append(f"{_fmt(spec.jitter_ms)}ms")
            if spec.delay_correlation_pct:
                parts.append(f"{_fmt(spec.delay_correlation_pct)}%")
        if spec.distribution != "uniform":
            parts += ["distribution", spec.distribution]
    if spec.gemodel is not None:
        g = spec.gemodel
        parts += ["loss", "gemodel"] + [
            f"{_fmt(v)}%" for v in (g.p_pct, g.r_pct, g.bad_loss_pct, g.good_loss_pct)
        ]
    elif spec.loss_pct or spec.loss_correlation_pct:
        parts += ["loss", f"{_fmt(spec.loss_pct)}%"]
        if spec.loss_correlation_pct:
            parts.append(f"{_fmt(spec.loss_correlation_pct)}%")
    for kw in ("duplicate", "corrupt", "reorder"):
        pct = getattr(spec, f"{kw}_pct")
        corr = getattr(spec, f"{kw}_correlation_pct")
        if pct or corr or (kw == "reorder" and spec.reorder_gap != d.reorder_gap):
            parts += [kw, f"{_fmt(pct)}%"]
            if corr:
                parts.append(f"{_fmt(corr)}%")
            if kw == "reorder" and spec.reorder_gap != d.reorder_gap:
                parts += ["gap", str(spec.reorder_gap)]
    if spec.rate_bps is not None:
        parts += ["rate", _fmt_rate(spec.rate_bps)]
    if spec.limit_packets != d.limit_packets:
        parts += ["limit", str(spec.limit_packets)]
    return " ".join(parts)

