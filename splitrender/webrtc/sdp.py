"""SDP edits for the front door (sans-IO): ICE candidates, when a shaping relay sits in the path.

With ``serve --webrtc-network``, each browser session's media go through an in-process
:class:`~splitrender.netsim.relay.Relay`: the browser is told the relay's listening
address as the server's only candidate, and the server is told the relay's server-side
socket as the browser's only candidate, so that neither end can find a path around it.
"""

from __future__ import annotations

import re

__all__ = ["host_candidate", "replace_candidates", "udp_candidate_ports", "strip_candidates"]

_CANDIDATE = re.compile(r"^a=candidate:(\S+) (\d+) (\S+) (\d+) (\S+) (\d+) typ (\S+)(.*)$")


def host_candidate(host: str, port: int, component: int = 1, foundation: str = "1") -> str:
    """An ``a=candidate`` line for a UDP host candidate (highest host priority)."""
    return f"a=candidate:{foundation} {component} udp 2130706431 {host} {port} typ host"


def udp_candidate_ports(sdp: str, host: str | None = None) -> list[int]:
    """The ports of the UDP candidates in ``sdp`` (only those on ``host`` when given), in order."""
    out = []
    for line in sdp.splitlines():
        m = _CANDIDATE.match(line.strip())
        if m and m.group(3).lower() == "udp" and (host is None or m.group(5) == host):
            out.append(int(m.group(6)))
    return out


def strip_candidates(sdp: str) -> str:
    """``sdp`` without its ``a=candidate`` and ``a=end-of-candidates`` lines."""
    lines = [ln for ln in sdp.splitlines() if not ln.startswith(("a=candidate:", "a=end-of-candidates"))]
    return "\r\n".join(lines) + "\r\n"


def replace_candidates(sdp: str, host: str, port: int) -> str:
    """``sdp`` with every media section's candidates replaced by one UDP host candidate ``host:port``
    (component 1: the session is bundled and RTCP-muxed), followed by ``a=end-of-candidates``."""
    out: list[str] = []
    in_media = False
    for ln in sdp.splitlines():
        if ln.startswith(("a=candidate:", "a=end-of-candidates")):
            continue
        if ln.startswith("m="):
            in_media = True
            out.append(ln)
            continue
        out.append(ln)
        if in_media and ln.startswith("c="):
            out.append(host_candidate(host, port))
            out.append("a=end-of-candidates")
    return "\r\n".join(out) + "\r\n"
