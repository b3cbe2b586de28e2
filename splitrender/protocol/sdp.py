"""SDP (RFC 4566) descriptions of one RTP video stream, as FFmpeg/PyAV open them.

Open the file with ``av.open(path, options={"protocol_whitelist": "file,udp,rtp"})``
or ``ffmpeg -protocol_whitelist file,udp,rtp -i stream.sdp``.
"""

from __future__ import annotations

import base64
import binascii
import ipaddress
from collections.abc import Sequence

from splitrender.protocol.annexb import Codec, nal_type
from splitrender.protocol.errors import SdpError

__all__ = ["RTPMAP_NAMES", "make_sdp", "parse_fmtp", "parameter_sets_from_sdp"]

RTPMAP_NAMES: dict[str, str] = {"h264": "H264", "hevc": "H265"}
CLOCK_RATE_HZ = 90000
H264_SPS, H264_PPS = 7, 8
HEVC_VPS, HEVC_SPS, HEVC_PPS = 32, 33, 34


def _b64(nal: bytes) -> str:
    return base64.b64encode(nal).decode("ascii")


def make_sdp(
    codec: Codec,
    port: int,
    payload_type: int,
    address: str = "127.0.0.1",
    session_name: str = "splitrender",
    parameter_sets: Sequence[bytes] = (),
) -> str:
    """SDP text for one video stream received on ``address:port``.

    ``parameter_sets`` are optional NAL units (H.264 SPS/PPS, HEVC VPS/SPS/PPS) put in
    ``sprop-*`` fmtp parameters; without them the stream must carry them in-band.
    """
    if codec not in RTPMAP_NAMES:
        raise ValueError(f"unknown codec {codec!r}")
    ip = ipaddress.ip_address(address)
    net = "IP4" if ip.version == 4 else "IP6"
    fmtp: list[str] = []
    if codec == "h264":
        fmtp.append("packetization-mode=1")
        sps = [n for n in parameter_sets if nal_type("h264", n) == H264_SPS]
        if sps and len(sps[0]) >= 4:
            fmtp.append(f"profile-level-id={sps[0][1:4].hex()}")
        if parameter_sets:
            fmtp.append("sprop-parameter-sets=" + ",".join(_b64(n) for n in parameter_sets))
    else:
        for name, t in (("vps", HEVC_VPS), ("sps", HEVC_SPS), ("pps", HEVC_PPS)):
            sets = [n for n in parameter_sets if nal_type("hevc", n) == t]
            if sets:
                fmtp.append(f"sprop-{name}=" + ",".join(_b64(n) for n in sets))
    lines = [
        "v=0",
        f"o=- 0 0 IN {net} {address}",
        f"s={session_name}",
        f"c=IN {net} {address}",
        "t=0 0",
        f"m=video {port} RTP/AVP {payload_type}",
        f"a=rtpmap:{payload_type} {RTPMAP_NAMES[codec]}/{CLOCK_RATE_HZ}",
    ]
    if fmtp:
        lines.append(f"a=fmtp:{payload_type} " + "; ".join(fmtp))
    return "\r\n".join(lines) + "\r\n"


def parse_fmtp(sdp: str) -> dict[str, str]:
    """Parameters of the first ``a=fmtp`` line (keys lower-cased)."""
    for line in sdp.splitlines():
        line = line.strip()
        if line.startswith("a=fmtp:"):
            _, _, params = line.partition(" ")
            out: dict[str, str] = {}
            for item in params.split(";"):
                key, sep, value = item.strip().partition("=")
                if sep:
                    out[key.strip().lower()] = value.strip()
            return out
    return {}


def parameter_sets_from_sdp(sdp: str) -> list[bytes]:
    """NAL units from ``sprop-parameter-sets`` (H.264) or ``sprop-vps/sps/pps`` (HEVC)."""
    fmtp = parse_fmtp(sdp)
    nals: list[bytes] = []
    for key in ("sprop-parameter-sets", "sprop-vps", "sprop-sps", "sprop-pps"):
        for item in fmtp.get(key, "").split(","):
            if not item:
                continue
            try:
                nals.append(base64.b64decode(item, validate=True))
            except (binascii.Error, ValueError):
                raise SdpError(f"SDP fmtp {key}: invalid base64 {item[:32]!r}") from None
    return nals
