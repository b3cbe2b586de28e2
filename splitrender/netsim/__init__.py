"""Network models (sans-IO, seeded) and the asyncio shaping relay.

The same :class:`Link` model drives the virtual-time simulator and the live
:class:`Relay`.  Specs come from named profiles (:func:`get_profile`), netem-style
strings (:func:`parse_netem`, :func:`parse_path`) or dicts/TOML
(:meth:`PathSpec.from_dict`, :meth:`PathSpec.from_toml`).
"""

from splitrender.netsim.config import (
    PROFILES,
    get_profile,
    parse_path,
    profile_names,
)
from splitrender.netsim.models import (
    DEFAULT_LIMIT_PACKETS,
    DEFAULT_RTO_S,
    DISTRIBUTIONS,
    MAHIMAHI_MTU_BYTES,
    Delivery,
    Distribution,
    GilbertElliott,
    Link,
    LinkSpec,
    PathSpec,
    corrupt,
    link_from_dict,
    link_to_dict,
    load_mahimahi_trace,
    path_from_dict,
    path_from_toml,
)
from splitrender.netsim.netem import parse_netem, to_netem
from splitrender.netsim.relay import DirectionStats, Relay, RelayStats, serve_relay

__all__ = [
    "DEFAULT_LIMIT_PACKETS",
    "DEFAULT_RTO_S",
    "DISTRIBUTIONS",
    "MAHIMAHI_MTU_BYTES",
    "PROFILES",
    "Delivery",
    "DirectionStats",
    "Distribution",
    "GilbertElliott",
    "Link",
    "LinkSpec",
    "PathSpec",
    "Relay",
    "RelayStats",
    "corrupt",
    "get_profile",
    "link_from_dict",
    "link_to_dict",
    "load_mahimahi_trace",
    "parse_netem",
    "parse_path",
    "path_from_dict",
    "path_from_toml",
    "profile_names",
    "serve_relay",
    "to_netem",
]
