"""Named network profiles, the dict/TOML form of a path, and :func:`parse_path`.

Profiles ``lan`` (20 +- 10 ms one way) and ``cloud`` (50 +- 20 ms one way), both with
uniform jitter, are the network conditions of the QUASAR paper's evaluation (Sec. 6:
"20 ms (with +-10 ms jitter) and 50 ms (with +-20 ms jitter)").  ``wifi`` and ``lte``
are illustrative examples with loss and rate limits, not taken from any paper.
"""

from __future__ import annotations

import dataclasses
import re
import tomllib
from pathlib import Path
from typing import Any

from splitrender.errors import NetworkConfigError
from splitrender.netsim.models import GilbertElliott, LinkSpec, PathSpec
from splitrender.netsim.netem import parse_netem

_LAN = LinkSpec(delay_ms=20.0, jitter_ms=10.0, distribution="uniform")
_CLOUD = LinkSpec(delay_ms=50.0, jitter_ms=20.0, distribution="uniform")

PROFILES: dict[str, PathSpec] = {
    "ideal": PathSpec(),
    "lan": PathSpec.symmetric(_LAN),
    "cloud": PathSpec.symmetric(_CLOUD),
    "wifi": PathSpec(
        uplink=LinkSpec(
            delay_ms=4.0, jitter_ms=2.0, gemodel=GilbertElliott(0.5, 40.0),
            rate_bps=40e6, limit_packets=500,
        ),
        downlink=LinkSpec(
            delay_ms=4.0, jitter_ms=2.0, gemodel=GilbertElliott(0.5, 40.0),
            rate_bps=100e6, limit_packets=1000,
        ),
    ),
    "lte": PathSpec(
        uplink=LinkSpec(
            delay_ms=35.0, jitter_ms=8.0, distribution="normal", loss_pct=0.5,
            rate_bps=10e6, limit_packets=300,
        ),
        downlink=LinkSpec(
            delay_ms=35.0, jitter_ms=8.0, distribution="normal", loss_pct=0.5,
            rate_bps=30e6, limit_packets=300,
        ),
    ),
}


def profile_names() -> list[str]:
    """Valid profile names, sorted."""
    return sorted(PROFILES)


def get_profile(name: str) -> PathSpec:
    """The named profile; :class:`NetworkConfigError` lists the valid names otherwise."""
    try:
        return PROFILES[name]
    except (KeyError, TypeError):
        raise NetworkConfigError(
            f"unknown network profile {name!r} (valid: {', '.join(profile_names())})"
        ) from None


_LINK_FIELDS = {f.name: f for f in dataclasses.fields(LinkSpec)}
_GE_FIELDS = {f.name for f in dataclasses.fields(GilbertElliott)}
_INT_KEYS = {"reorder_gap", "limit_packets"}
_STR_KEYS = {"distribution", "trace_path"}


def _check_type(where: str, key: str, value: Any) -> None:
    if key == "keep_order":
        ok = isinstance(value, bool)
        want = "true or false"
    elif key in _INT_KEYS:
        ok = isinstance(value, int) and not isinstance(value, bool)
        want = "an integer"
    elif key in _STR_KEYS:
        ok = isinstance(value, str)
        want = "a string"
    elif key == "gemodel":
        ok = isinstance(value, dict)
        want = "a table with " + ", ".join(sorted(_GE_FIELDS))
    else:
        ok = isinstance(value, (int, float)) and not isinstance(value, bool)
        want = "a number"
    if not ok:
        raise NetworkConfigError(f"{where}.{key} must be {want}, got {value!r}")


def link_from_dict(data: Any, where: str = "link") -> LinkSpec:
    """Build a :class:`LinkSpec` from a dict of its field names (``gemodel`` a sub-dict)."""
    if not isinstance(data, dict):
        raise NetworkConfigError(f"{where} must be a table/dict, got {type(data).__name__}")
    kwargs: dict[str, Any] = {}
    for key, value in data.items():
        if key not in _LINK_FIELDS:
            raise NetworkConfigError(
                f"{where}: unknown key {key!r} (valid: {', '.join(sorted(_LINK_FIELDS))})"
            )
        if key in ("rate_bps", "trace_path") and value is None:
            kwargs[key] = None
            continue
        _check_type(where, key, value)
        if key == "gemodel":
            for gk, gv in value.items():
                if gk not in _GE_FIELDS:
                    raise NetworkConfigError(
                        f"{where}.gemodel: unknown key {gk!r} (valid: {', '.join(sorted(_GE_FIELDS))})"
                    )
                _check_type(f"{where}.gemodel", gk, gv)
            if "p_pct" not in value:
                raise NetworkConfigError(f"{where}.gemodel: missing key 'p_pct'")
            try:
                value = GilbertElliott(**value)
            except NetworkConfigError as exc:
                raise NetworkConfigError(f"{where}.{exc}") from None
        kwargs[key] = value
    try:
        return LinkSpec(**kwargs)
    except NetworkConfigError as exc:
        raise NetworkConfigError(f"{where}.{exc}") from None


def link_to_dict(spec: LinkSpec) -> dict[str, Any]:
    """The non-default fields of ``spec`` as a dict (``link_from_dict`` inverts it)."""
    default = LinkSpec()
    out: dict[str, Any] = {}
    for name in _LINK_FIELDS:
        value = getattr(spec, name)
        if value != getattr(default, name):
            out[name] = dataclasses.asdict(value) if isinstance(value, GilbertElliott) else value
    return out


def path_from_dict(data: Any) -> PathSpec:
    """``{"uplink": {...}, "downlink": {...}}`` -> :class:`PathSpec`; missing side = ideal."""
    if not isinstance(data, dict):
        raise NetworkConfigError(f"network path must be a table/dict, got {type(data).__name__}")
    for key in data:
        if key not in ("uplink", "downlink"):
            raise NetworkConfigError(
                f"network path: unknown key {key!r} (valid: downlink, uplink)"
            )
    return PathSpec(
        uplink=link_from_dict(data.get("uplink", {}), "uplink"),
        downlink=link_from_dict(data.get("downlink", {}), "downlink"),
    )


def path_from_toml(path: str | Path, table: str | None = None) -> PathSpec:
    """Load a :class:`PathSpec` from a TOML file, optionally from a dotted ``table``."""
    p = Path(path)
    try:
        with p.open("rb") as fh:
            data: Any = tomllib.load(fh)
    except OSError as exc:
        raise NetworkConfigError(f"{str(p)!r}: cannot read: {exc}") from exc
    except tomllib.TOMLDecodeError as exc:
        raise NetworkConfigError(f"{str(p)!r}: invalid TOML: {exc}") from exc
    if table:
        for part in table.split("."):
            if not isinstance(data, dict) or part not in data:
                raise NetworkConfigError(f"{str(p)!r}: no table [{table}]")
            data = data[part]
    try:
        return path_from_dict(data)
    except NetworkConfigError as exc:
        raise NetworkConfigError(f"{str(p)!r}: {exc}") from None


_DIRECTION_RE = re.compile(r"^\s*(up|down|uplink|downlink)\s*:", re.IGNORECASE)


def _side(text: str, direction: str) -> LinkSpec:
    name = text.strip()
    if name in PROFILES:
        profile = PROFILES[name]
        return profile.uplink if direction == "uplink" else profile.downlink
    return parse_netem(text)


def parse_path(text: str) -> PathSpec:
    """A profile name, a ``.toml`` file, a netem string (both directions alike) or
    ``"up: ...; down: ..."``.

    Each side of the directional form is itself a profile name (its own direction of
    that profile is used) or a netem string; a side not given is ideal.
    """
    if not isinstance(text, str):
        raise NetworkConfigError(f"network path: expected a string, got {type(text).__name__}")
    name = text.strip()
    if name in PROFILES:
        return PROFILES[name]
    if name.lower().endswith(".toml"):
        return path_from_toml(name)
    if _DIRECTION_RE.match(text) is None:
        return PathSpec.symmetric(parse_netem(text))
    sides: dict[str, LinkSpec] = {}
    for part in text.split(";"):
        if not part.strip():
            continue
        m = _DIRECTION_RE.match(part)
        if m is None:
            raise NetworkConfigError(
                f"network path: {part.strip()!r} does not start with 'up:' or 'down:'"
            )
        direction = "uplink" if m.group(1).lower().startswith("up") else "downlink"
        if direction in sides:
            raise NetworkConfigError(f"network path: {direction} given twice")
        try:
            sides[direction] = _side(part[m.end():], direction)
        except NetworkConfigError as exc:
            raise NetworkConfigError(f"{direction}: {exc}") from None
    return PathSpec(**sides)
