"""Sequence parameter set fields (H.264 7.3.2.1.1, H.265 7.3.2.2) for SDP parameters.

A small MSB-first bit reader with Exp-Golomb codes (H.264 9.1) over the RBSP (the NAL
payload with emulation-prevention bytes removed).  Only the fields an SDP offer names
are read: profile, constraint flags, level (RFC 6184 ``profile-level-id``; RFC 7798
``profile-id``, ``tier-flag``, ``level-id``), chroma format, bit depth and the coded
picture size.  Malformed or truncated input raises :class:`SdpError`.
"""

from __future__ import annotations

from dataclasses import dataclass

from splitrender.protocol.errors import SdpError

__all__ = ["BitReader", "nal_to_rbsp", "H264Sps", "HevcSps", "parse_h264_sps", "parse_hevc_sps"]


def nal_to_rbsp(payload: bytes) -> bytes:
    """Remove emulation-prevention bytes (``00 00 03`` -> ``00 00``)."""
    if b"\x00\x00\x03" not in payload:
        return bytes(payload)
    out = bytearray()
    zeros = 0
    for b in payload:
        if zeros >= 2 and b == 3:
            zeros = 0
            continue
        out.append(b)
        zeros = zeros + 1 if b == 0 else 0
    return bytes(out)


class BitReader:
    """MSB-first reader of ``u(n)``, ``ue(v)`` and ``se(v)`` fields."""

    def __init__(self, data: bytes) -> None:
        self._data = data
        self._pos = 0
        self._end = 8 * len(data)

    @property
    def bits_left(self) -> int:
        return self._end - self._pos

    def u(self, n: int) -> int:
        if n > self.bits_left:
            raise SdpError(f"parameter set truncated: needs {n} more bits, {self.bits_left} left")
        v = 0
        for _ in range(n):
            v = (v << 1) | (self._data[self._pos >> 3] >> (7 - (self._pos & 7)) & 1)
            self._pos += 1
        return v

    def skip(self, n: int) -> None:
        if n > self.bits_left:
            raise SdpError(f"parameter set truncated: cannot skip {n} bits, {self.bits_left} left")
        self._pos += n

    def ue(self) -> int:
        zeros = 0
        while self.u(1) == 0:
            zeros += 1
            if zeros > 31:
                raise SdpError("Exp-Golomb code longer than 32 bits")
        return (1 << zeros) - 1 + self.u(zeros)

    def se(self) -> int:
        k = self.ue()
        return (k + 1) // 2 if k & 1 else -(k // 2)


@dataclass(frozen=True)
class H264Sps:
    profile_idc: int
    constraint_flags: int
    """The byte of constraint_set0..5 flags and two reserved bits."""
    level_idc: int
    sps_id: int
    chroma_format_idc: int
    bit_depth_luma: int
    width: int
    """Displayed width (coded width less the cropping window)."""
    height: int

    @property
    def profile_level_id(self) -> str:
        """RFC 6184 ``profile-level-id``: the three bytes as six hex digits."""
        return f"{self.profile_idc:02x}{self.constraint_flags:02x}{self.level_idc:02x}"


@dataclass(frozen=True)
class HevcSps:
    profile_space: int
    tier_flag: int
    profile_idc: int
    compatibility_flags: int
    """32 general_profile_compatibility_flag bits."""
    constraint_flags: int
    """48 bits: progressive/interlaced/non-packed/frame-only flags and reserved bits."""
    level_idc: int
    sps_id: int
    chroma_format_idc: int
    bit_depth_luma: int
    width: int
    height: int


_H264_HIGH_PROFILES = {100, 110, 122, 244, 44, 83, 86, 118, 128, 138, 139, 134, 135}


def _skip_scaling_list(r: BitReader, size: int) -> None:
    last = nxt = 8
    for _ in range(size):
        if nxt:
            nxt = (last + r.se() + 256) % 256
        last = nxt or last


def parse_h264_sps(nal: bytes) -> H264Sps:
    """Fields of an H.264 SPS NAL unit (with its one-byte header, type 7)."""
    if len(nal) < 4 or nal[0] & 0x1F != 7:
        raise SdpError(f"not an H.264 SPS NAL unit ({nal[:4].hex()})")
    r = BitReader(nal_to_rbsp(nal[1:]))
    profile, flags, level = r.u(8), r.u(8), r.u(8)
    sps_id = r.ue()
    chroma, depth = 1, 8
    if profile in _H264_HIGH_PROFILES:
        chroma = r.ue()
        if chroma == 3:
            r.skip(1)  # separate_colour_plane_flag
        depth = r.ue() + 8
        r.ue()  # bit_depth_chroma_minus8
        r.skip(1)  # qpprime_y_zero_transform_bypass_flag
        if r.u(1):  # seq_scaling_matrix_present_flag
            for i in range(8 if chroma != 3 else 12):
                if r.u(1):
                    _skip_scaling_list(r, 16 if i < 6 else 64)
    r.ue()  # log2_max_frame_num_minus4
    poc_type = r.ue()
    if poc_type == 0:
        r.ue()
    elif poc_type == 1:
        r.skip(1)
        r.se()
        r.se()
        for _ in range(min(r.ue(), 255)):
            r.se()
    r.ue()  # max_num_ref_frames
    r.skip(1)  # gaps_in_frame_num_value_allowed_flag
    w_mbs, h_map = r.ue() + 1, r.ue() + 1
    frame_mbs_only = r.u(1)
    if not frame_mbs_only:
        r.skip(1)
    r.skip(1)  # direct_8x8_inference_flag
    width, height = 16 * w_mbs, 16 * h_map * (2 - frame_mbs_only)
    if r.u(1):  # frame_cropping_flag
        left, right, top, bottom = r.ue(), r.ue(), r.ue(), r.ue()
        cx = 2 if chroma in (1, 2) else 1
        cy = (2 if chroma == 1 else 1) * (2 - frame_mbs_only)
        if chroma == 0:
            cx, cy = 1, 2 - frame_mbs_only
        width -= cx * (left + right)
        height -= cy * (top + bottom)
    return H264Sps(profile, flags, level, sps_id, chroma, depth, width, height)


def parse_hevc_sps(nal: bytes) -> HevcSps:
    """Fields of an HEVC SPS NAL unit (with its two-byte header, type 33)."""
    if len(nal) < 3 or (nal[0] >> 1) & 0x3F != 33:
        raise SdpError(f"not an HEVC SPS NAL unit ({nal[:4].hex()})")
    r = BitReader(nal_to_rbsp(nal[2:]))
    r.skip(4)  # sps_video_parameter_set_id
    max_sub_layers = r.u(3) + 1
    r.skip(1)  # sps_temporal_id_nesting_flag
    # profile_tier_level(1, sps_max_sub_layers_minus1), 7.3.3
    space, tier, profile = r.u(2), r.u(1), r.u(5)
    compat = r.u(32)
    constraints = r.u(48)
    level = r.u(8)
    sub_profile, sub_level = [], []
    for _ in range(max_sub_layers - 1):
        sub_profile.append(r.u(1))
        sub_level.append(r.u(1))
    if max_sub_layers > 1:
        r.skip(2 * (8 - (max_sub_layers - 1)))
    for p, lv in zip(sub_profile, sub_level):
        r.skip(88 * p + 8 * lv)
    sps_id = r.ue()
    chroma = r.ue()
    if chroma == 3:
        r.skip(1)
    width, height = r.ue(), r.ue()
    if r.u(1):  # conformance_window_flag
        left, right, top, bottom = r.ue(), r.ue(), r.ue(), r.ue()
        cx = 2 if chroma in (1, 2) else 1
        cy = 2 if chroma == 1 else 1
        width -= cx * (left + right)
        height -= cy * (top + bottom)
    depth = r.ue() + 8
    return HevcSps(space, tier, profile, compat, constraints, level, sps_id, chroma, depth, width, height)
