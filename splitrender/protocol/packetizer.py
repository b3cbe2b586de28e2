"""Codec-generic RTP packetizer/depacketizer for Annex-B access units."""

from __future__ import annotations

import logging
from collections.abc import Iterable

from splitrender.protocol.annexb import Codec, join_annexb, split_annexb
from splitrender.protocol.data import data_depayload, data_payloads
from splitrender.protocol.h264 import h264_depayload, h264_payloads
from splitrender.protocol.h265 import h265_depayload, h265_payloads
from splitrender.protocol.rtp import RtpPacket

__all__ = ["DEFAULT_MTU", "RtpPacketizer", "payloads_for", "depacketize"]

logger = logging.getLogger(__name__)

DEFAULT_MTU = 1200
"""Default largest RTP payload in bytes (fits a 1280-byte IPv6 path with headers)."""


def payloads_for(codec: Codec, access_unit: bytes, mtu: int = DEFAULT_MTU) -> list[bytes]:
    """RTP payloads for one Annex-B access unit (RFC 6184 / RFC 7798) or data frame."""
    if codec == "data":
        return data_payloads(access_unit, mtu)
    nals = split_annexb(access_unit)
    if codec == "h264":
        return h264_payloads(nals, mtu)
    if codec == "hevc":
        return h265_payloads(nals, mtu)
    raise ValueError(f"unknown codec {codec!r}")


def depacketize(codec: Codec, payloads: Iterable[bytes]) -> bytes:
    """Annex-B bytes from the RTP payloads of one access unit; raises ``PayloadError``."""
    if codec == "data":
        return data_depayload(payloads)[0]
    if codec == "h264":
        return join_annexb(h264_depayload(payloads))
    if codec == "hevc":
        return join_annexb(h265_depayload(payloads))
    raise ValueError(f"unknown codec {codec!r}")


class RtpPacketizer:
    """Turns access units into RTP packets with consecutive sequence numbers.

    The marker bit is set on the last packet of each access unit.
    """

    def __init__(
        self,
        codec: Codec,
        ssrc: int,
        payload_type: int,
        mtu: int = DEFAULT_MTU,
        first_sequence: int = 0,
        extension: tuple[int, bytes] | None = None,
    ) -> None:
        if codec not in ("h264", "hevc", "data"):
            raise ValueError(f"unknown codec {codec!r}")
        self.codec: Codec = codec
        self.ssrc = ssrc
        self.payload_type = payload_type
        self.mtu = mtu
        self.sequence_number = first_sequence & 0xFFFF
        """Sequence number the next packet will get."""
        self.extension = extension
        """(profile, body) of a header extension every packet carries (e.g. a transport sequence number reserved
        to be written at send time), or None."""
        self.packets_sent = 0
        self.octets_sent = 0
        """Payload bytes sent (RTCP sender report ``octet count``)."""

    def packetize(self, access_unit: bytes, timestamp: int) -> list[RtpPacket]:
        """Packets for one Annex-B access unit at ``timestamp`` (90 kHz units)."""
        payloads = payloads_for(self.codec, access_unit, self.mtu)
        seq, ts, last = self.sequence_number, timestamp & 0xFFFFFFFF, len(payloads) - 1
        packets = [
            RtpPacket(
                payload_type=self.payload_type,
                sequence_number=(seq + k) & 0xFFFF,
                timestamp=ts,
                ssrc=self.ssrc,
                payload=p,
                marker=k == last,
                extension_profile=self.extension[0] if self.extension else None,
                extension_data=self.extension[1] if self.extension else b"",
            )
            for k, p in enumerate(payloads)
        ]
        self.sequence_number = (seq + len(payloads)) & 0xFFFF
        self.packets_sent += len(payloads)
        self.octets_sent += sum(len(p) for p in payloads)
        return packets
