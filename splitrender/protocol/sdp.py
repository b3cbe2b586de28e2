"""SDP (RFC 4566) descriptions of one RTP video stream, as FFmpeg/PyAV open them.

The media line is ``RTP/AVPF`` (RFC 4585): the receiver sends generic NACKs and PLIs
(``a=rtcp-fb:<pt> nack``, ``nack pli`` and ``ccm fir``), RTP and RTCP share one port
(``a=rtcp-mux``, RFC 5761).  With the parameter sets the encoder sends, the ``fmtp``
line names the stream exactly: H.264 (RFC 6184) ``profile-level-id`` from the SPS and
``sprop-parameter-sets``; HEVC (RFC 7798) ``profile-id``, ``tier-flag``, ``level-id``
(and ``profile-space`` when not 0) from the SPS, and ``sprop-vps/sps/pps``.  The stream
repeats them in-band before every IDR as well.  4:4:4 colour (``chroma="444"``, or lossless)
is H.264 High 4:4:4 Predictive (``profile-level-id=f400..``) or an HEVC Range Extensions
profile (``profile-id=4``), whose fmtp also carries ``interop-constraints``, the SPS's 48
general constraint bits, since the Range Extensions profiles share profile-id 4 and only
those bits tell them apart (RFC 7798 7.1; absent, a receiver must infer them all zero
past the first four, which names none of those profiles).

``level-id`` names a real level (H.265 Table A.8, 30 x the level): our encoder writes
one into every SPS, lossless included (see :mod:`splitrender.codecs.video`).  An SPS from
elsewhere whose general_level_idc names none (255, level 8.5, or 0) gets, in the SDP only,
the lowest level that fits its picture size and its VUI frame rate
(:func:`splitrender.protocol.sps.hevc_level_idc`); without a frame rate it is left as is.

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
from splitrender.protocol.rtp import RTP_CLOCK_HZ
from splitrender.protocol.sps import HevcSps, hevc_level_idc, is_hevc_level, nal_to_rbsp, parse_hevc_sps

__all__ = ["RTPMAP_NAMES", "make_sdp", "parse_fmtp", "parameter_sets_from_sdp", "sdp_attributes"]

RTPMAP_NAMES: dict[str, str] = {"h264": "H264", "hevc": "H265"}
CLOCK_RATE_HZ = RTP_CLOCK_HZ
H264_SPS, H264_PPS = 7, 8
HEVC_VPS, HEVC_SPS, HEVC_PPS = 32, 33, 34
HEVC_REXT_PROFILE = 4
"""general_profile_idc of the Format Range Extensions profiles (H.265 A.3.5: Main 4:4:4, Monochrome, Main 4:4:4 10,
...), which share it and differ in the general constraint flags, so their SDP carries ``interop-constraints``."""


def _b64(nal: bytes) -> str:
    return base64.b64encode(nal).decode("ascii")


def _level_id(info: HevcSps) -> int:
    """RFC 7798 ``level-id``: the SPS's general_level_idc, or when that names no level of Table A.8 the lowest
    level that fits the SPS's picture size and VUI frame rate (when it has one)."""
    if is_hevc_level(info.level_idc) or info.frame_rate is None or info.width <= 0 or info.height <= 0:
        return info.level_idc
    return hevc_level_idc(info.width, info.height, float(info.frame_rate))


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
    ``sprop-*`` fmtp parameters, and whose SPS gives the profile and level parameters;
    other NAL types are left out.  Without them the fmtp line says only
    ``packetization-mode=1`` (H.264) and the stream must carry them in-band.  Pass the
    sets the encoder actually sends (:meth:`splitrender.codecs.video.VideoEncoder.parameter_sets`).
    """
    if codec not in RTPMAP_NAMES:
        raise ValueError(f"unknown codec {codec!r}")
    ip = ipaddress.ip_address(address)
    net = "IP4" if ip.version == 4 else "IP6"
    fmtp: list[str] = []
    parameter_sets = [n for n in parameter_sets if n]
    if codec == "h264":
        fmtp.append("packetization-mode=1")
        sps = [n for n in parameter_sets if nal_type("h264", n) == H264_SPS]
        pps = [n for n in parameter_sets if nal_type("h264", n) == H264_PPS]
        rbsp = nal_to_rbsp(sps[0][1:8]) if sps else b""
        if len(rbsp) >= 3:  # profile_idc, constraint flags, level_idc: the RBSP's first three bytes
            fmtp.append(f"profile-level-id={rbsp[:3].hex()}")
        if sps or pps:
            fmtp.append("sprop-parameter-sets=" + ",".join(_b64(n) for n in (*sps, *pps)))
    else:
        sps = [n for n in parameter_sets if nal_type("hevc", n) == HEVC_SPS]
        if sps:
            try:
                info = parse_hevc_sps(sps[0])
            except SdpError:
                info = None
            if info is not None:
                if info.profile_space:
                    fmtp.append(f"profile-space={info.profile_space}")
                fmtp += [f"profile-id={info.profile_idc}", f"tier-flag={info.tier_flag}", f"level-id={_level_id(info)}"]
                if info.profile_idc >= HEVC_REXT_PROFILE:  # profile-id 4 is 19 profiles: the constraint bits say which
                    fmtp.append(f"interop-constraints={info.interop_constraints}")
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
        f"m=video {port} RTP/AVPF {payload_type}",
        f"a=rtpmap:{payload_type} {RTPMAP_NAMES[codec]}/{CLOCK_RATE_HZ}",
    ]
    if fmtp:
        lines.append(f"a=fmtp:{payload_type} " + "; ".join(fmtp))
    lines += [f"a=rtcp-fb:{payload_type} nack", f"a=rtcp-fb:{payload_type} nack pli",
              f"a=rtcp-fb:{payload_type} ccm fir", "a=rtcp-mux"]
    return "\r\n".join(lines) + "\r\n"


def sdp_attributes(sdp: str, name: str) -> list[str]:
    """Values of every ``a=<name>:<value>`` line (``""`` for a flag ``a=<name>``)."""
    out = []
    for line in sdp.splitlines():
        line = line.strip()
        if line == f"a={name}":
            out.append("")
        elif line.startswith(f"a={name}:"):
            out.append(line[len(name) + 3:])
    return out


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
