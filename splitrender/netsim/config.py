"""Named network profiles and :func:`parse_path` (profile name, TOML file or netem string).

The dict/TOML form of a path (:func:`path_from_dict`, :func:`path_from_toml`, ...) is
:mod:`.models`' and re-exported here.

Profiles ``lan`` (20 +- 10 ms one way) and ``cloud`` (50 +- 20 ms one way), both with
uniform jitter, are the network conditions of the QUASAR paper's evaluation (Sec. 6:
"20 ms (with +-10 ms jitter) and 50 ms (with +-20 ms jitter)").  ``wifi`` and ``lte``
are illustrative examples with loss and rate limits, not taken from any paper.
"""

from __future__ import annotations

import re

from splitrender.errors import NetworkConfigError
from splitrender.netsim.models import (  # the dict/TOML form is re-exported where it was
    GilbertElliott,
    LinkSpec,
    PathSpec,
    link_from_dict,
    link_to_dict,
    path_from_dict,
    path_from_toml,
)
from splitrender.netsim.netem import parse_netem

__all__ = ["PROFILES", "get_profile", "link_from_dict", "link_to_dict", "parse_path", "path_from_dict", "path_from_toml",
           "profile_names"]

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
