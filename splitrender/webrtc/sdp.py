"""SDP checks and edits for the front door (sans-IO): the page's offer checked before aiortc reads it, and ICE
candidates, when a shaping relay sits in the path.

:func:`check_offer` refuses, by name, the offers that aiortc would fail on with an exception of its own
(``RuntimeError``, ``ValueError``, ``AttributeError``: a payload type used but never mapped, a media section
with no direction or no ``a=mid``, no data channel section, no ICE credentials or DTLS set-up).

With ``serve --webrtc-network``, each browser session's media go through an in-process
:class:`~splitrender.netsim.relay.Relay`: the browser is told the relay's listening
address as the server's only candidate, and the server is told the relay's server-side
socket as the browser's only candidate, so that neither end can find a path around it.
"""

from __future__ import annotations

import re

from .messages import PageMessageError

__all__ = ["check_offer", "SdpOfferError", "MAX_SDP_LINES", "host_candidate", "replace_candidates",
           "udp_candidate_ports", "strip_candidates"]

MAX_SDP_LINES = 2000
"""Most lines an offer may have (a browser's offer of one video and one data channel section has about 150)."""
_DIRECTIONS = ("sendrecv", "sendonly", "recvonly", "inactive")
_MEDIA = re.compile(r"^m=(\S+) (\d+)(?:/\d+)? (\S+) (.*)$")
_PT_ATTR = re.compile(r"^a=(rtpmap|fmtp|rtcp-fb):(\d{1,3})[ /]")


class SdpOfferError(PageMessageError):
    """The page's offer is one this server cannot take; the text names the section and what is missing."""


def check_offer(sdp: str) -> None:
    """Raise :class:`SdpOfferError` unless ``sdp`` is an offer the front door can answer: SDP lines, exactly one
    ``m=video`` section (the page receives it: ``recvonly`` or ``sendrecv``) with an ``a=rtpmap`` for
    ``H264/90000`` and a map for every dynamic payload type it lists or describes, one ``m=application`` data
    channel section, an ``a=mid`` (unique) in every section, ICE credentials, a DTLS fingerprint and set-up role."""
    def bad(text: str) -> SdpOfferError:
        return SdpOfferError(f"session request.sdp: not an offer this server can take ({text})"[:300])

    lines = [ln.rstrip("\r") for ln in sdp.split("\n")]
    while lines and not lines[-1]:
        lines.pop()
    if len(lines) > MAX_SDP_LINES:
        raise bad(f"{len(lines)} lines, more than the {MAX_SDP_LINES} allowed")
    session: list[str] = []
    sections: list[tuple[int, str, list[str]]] = []
    for i, ln in enumerate(lines):
        if len(ln) < 2 or ln[1] != "=" or not ln[0].isalpha():
            raise bad(f"line {i + 1} is not an SDP line: {ln[:40]!r}")
        if ln.startswith("m="):
            sections.append((i + 1, ln, []))
        elif sections:
            sections[-1][2].append(ln)
        else:
            session.append(ln)
    if not lines or lines[0] != "v=0":
        raise bad("the first line is not v=0")

    def attr(where: list[str], name: str) -> list[str]:
        return [ln[len(name) + 3:] for ln in where if ln.startswith(f"a={name}:") or ln == f"a={name}"]

    kinds = [(_MEDIA.match(m).group(1) if _MEDIA.match(m) else "") for _, m, _ in sections]
    if kinds.count("video") != 1:
        raise bad(f"{kinds.count('video')} m=video sections, expected 1 (the page receives one video track)")
    if kinds.count("application") != 1:
        raise bad(f"{kinds.count('application')} m=application sections, expected 1 (the page's data channels)")
    mids: set[str] = set()
    for k, (n, m_line, body) in enumerate(sections):
        m = _MEDIA.match(m_line)
        where = f"media section {k} (line {n})"
        if m is None:
            raise bad(f"{where}: {m_line[:60]!r} is not 'm=KIND PORT PROTO FORMATS'")
        kind, proto, fmts = m.group(1), m.group(3), m.group(4).split()
        mid = attr(body, "mid")
        if len(mid) != 1 or not mid[0]:
            raise bad(f"{where}: {'no' if not mid else len(mid)} a=mid lines, expected one")
        if mid[0] in mids:
            raise bad(f"{where}: a=mid:{mid[0]} is used twice")
        mids.add(mid[0])
        for name, label in (("ice-ufrag", "ICE username fragment"), ("ice-pwd", "ICE password"),
                            ("fingerprint", "DTLS fingerprint"), ("setup", "DTLS set-up role")):
            values = attr(body, name) or attr(session, name)
            if not values or not values[0].strip():
                raise bad(f"{where}: no a={name} ({label}) in the section or the session")
            if name == "setup" and values[0].strip() not in ("actpass", "active", "passive"):
                raise bad(f"{where}: a=setup:{values[0][:20]} is not actpass, active or passive")
        if kind == "application":
            if "webrtc-datachannel" not in fmts or "SCTP" not in proto:
                raise bad(f"{where}: m=application is not 'UDP/DTLS/SCTP webrtc-datachannel'")
            continue
        if kind != "video":
            continue                # aiortc answers other sections as rejected
        if not all(f.isdigit() and int(f) < 128 for f in fmts):
            raise bad(f"{where}: payload types {' '.join(fmts)[:60]!r} are not all numbers below 128")
        listed = {int(f) for f in fmts}
        directions = [ln[2:] for ln in body if ln[2:] in _DIRECTIONS]
        if len(directions) != 1:
            raise bad(f"{where}: {'no' if not directions else len(directions)} direction attributes "
                      "(a=recvonly, a=sendrecv, ...), expected one")
        if directions[0] not in ("recvonly", "sendrecv"):
            raise bad(f"{where}: a={directions[0]}, but the page must receive the video (a=recvonly)")
        mapped: dict[int, str] = {}
        for ln in body:
            pm = _PT_ATTR.match(ln)
            if ln.startswith(("a=rtpmap:", "a=fmtp:", "a=rtcp-fb:")) and pm is None:
                raise bad(f"{where}: {ln[:60]!r} has no payload type")
            if pm is None:
                continue
            pt = int(pm.group(2))
            if pt not in listed:
                raise bad(f"{where}: {ln[:40]!r} describes payload type {pt}, which the m= line does not list")
            if pm.group(1) == "rtpmap":
                mapped[pt] = ln.split(" ", 1)[1] if " " in ln else ""
            elif pt not in mapped and pt >= 96:
                raise bad(f"{where}: {ln[:40]!r} comes before (or without) a=rtpmap:{pt}")
        unmapped = sorted(pt for pt in listed if pt >= 96 and pt not in mapped)
        if unmapped:
            raise bad(f"{where}: dynamic payload type {unmapped[0]} has no a=rtpmap")
        if not any(v.upper().startswith("H264/90000") for v in mapped.values()):
            raise bad(f"{where}: no a=rtpmap for H264/90000 (the page must offer H.264)")

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
