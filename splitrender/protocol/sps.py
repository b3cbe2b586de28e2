"""Sequence parameter set fields (H.264 7.3.2.1.1, H.265 7.3.2.2) for SDP parameters.

A small MSB-first bit reader with Exp-Golomb codes (H.264 9.1) over the RBSP (the NAL
payload with emulation-prevention bytes removed).  Only the fields an SDP offer names
are read: profile, constraint flags, level (RFC 6184 ``profile-level-id``; RFC 7798
``profile-id``, ``tier-flag``, ``level-id``), chroma format, bit depth and the coded
picture size, and for HEVC the frame rate of the VUI timing information.  Malformed or
truncated input raises :class:`SdpError`.

HEVC levels (H.265 Annex A): :func:`hevc_level_idc` is the lowest level of Table A.8
whose picture size and luma sample rate limits fit a stream, and :func:`set_hevc_level`
rewrites general_level_idc in a VPS or SPS.  x265 writes level_idc 255 (level 8.5, no
limits) in lossless mode and refuses ``level-idc`` there (lossless is constant QP, and
x265 will not promise a level's bit rate under constant QP), so
:class:`splitrender.codecs.video.VideoEncoder` puts the level computed here into its
parameter sets instead.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from fractions import Fraction

from splitrender.protocol.errors import SdpError

__all__ = ["BitReader", "nal_to_rbsp", "rbsp_to_nal", "H264Sps", "HevcSps", "parse_h264_sps", "parse_hevc_sps",
           "HEVC_LEVELS", "HEVC_LEVEL_UNCONSTRAINED", "hevc_level_idc", "is_hevc_level", "hevc_level_of",
           "set_hevc_level"]


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


def rbsp_to_nal(rbsp: bytes) -> bytes:
    """Insert emulation-prevention bytes (H.264 7.4.1, H.265 7.4.2): ``00 00`` before a byte
    of 0..3 becomes ``00 00 03``; also after a final ``00 00``.  The inverse of :func:`nal_to_rbsp`."""
    out = bytearray()
    zeros = 0
    for b in rbsp:
        if zeros >= 2 and b <= 3:
            out.append(3)
            zeros = 0
        out.append(b)
        zeros = zeros + 1 if b == 0 else 0
    if zeros >= 2:
        out.append(3)
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
    frame_rate: Fraction | None = None
    """vui_time_scale / vui_num_units_in_tick, when the SPS's VUI carries timing information
    (x265 writes it); None when it does not, or the SPS ends (or is malformed) before it."""

    @property
    def interop_constraints(self) -> str:
        """RFC 7798 ``interop-constraints``: the 48 constraint bits as twelve hex digits.  For the Range Extensions
        profiles (profile_idc 4: Main 4:4:4, Monochrome, ...) these bits tell the profiles apart, e.g. ``9e0800000000``
        (max 12, 10 and 8 bits, no 4:2:2 or 4:2:0 limit, lower bit rate) for Main 4:4:4."""
        return f"{self.constraint_flags:012x}"


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
    try:
        rate = _hevc_sps_frame_rate(r, max_sub_layers)
    except SdpError:
        rate = None
    return HevcSps(space, tier, profile, compat, constraints, level, sps_id, chroma, depth, width, height, rate)


def _check(value: int, top: int, what: str) -> int:
    if value > top:
        raise SdpError(f"HEVC SPS {what}: {value} exceeds {top}")
    return value


def _skip_hevc_scaling_list_data(r: BitReader) -> None:
    """scaling_list_data() (H.265 7.3.4)."""
    for size_id in range(4):
        for _ in range(0, 6, 3 if size_id == 3 else 1):
            if not r.u(1):  # scaling_list_pred_mode_flag
                r.ue()  # scaling_list_pred_matrix_id_delta
                continue
            if size_id > 1:
                r.se()  # scaling_list_dc_coef_minus8
            for _ in range(min(64, 1 << (4 + (size_id << 1)))):
                r.se()  # scaling_list_delta_coef


def _skip_st_ref_pic_set(r: BitReader, idx: int, num_delta_pocs: list[int]) -> None:
    """st_ref_pic_set(idx) (H.265 7.3.7) as it appears in an SPS; appends its NumDeltaPocs."""
    if idx and r.u(1):  # inter_ref_pic_set_prediction_flag (delta_idx_minus1 only in slice headers)
        r.skip(1)  # delta_rps_sign
        r.ue()  # abs_delta_rps_minus1
        n = 0
        for _ in range(num_delta_pocs[idx - 1] + 1):
            used = r.u(1)  # used_by_curr_pic_flag
            n += 1 if used else r.u(1)  # use_delta_flag (inferred 1 when used)
        num_delta_pocs.append(n)
        return
    neg = _check(r.ue(), 16, "num_negative_pics")
    pos = _check(r.ue(), 16, "num_positive_pics")
    for _ in range(neg + pos):
        r.ue()  # delta_poc_s0/s1_minus1
        r.skip(1)  # used_by_curr_pic_s0/s1_flag
    num_delta_pocs.append(neg + pos)


def _hevc_sps_frame_rate(r: BitReader, max_sub_layers: int) -> Fraction | None:
    """The rest of seq_parameter_set_rbsp() (H.265 7.3.2.2.1) after bit_depth_luma_minus8, up to the VUI's
    timing information (E.2.1): its frame rate, or None when there is none."""
    r.ue()  # bit_depth_chroma_minus8
    log2_max_poc_lsb = _check(r.ue(), 12, "log2_max_pic_order_cnt_lsb_minus4") + 4
    ordering_all = r.u(1)
    for _ in range(max_sub_layers if ordering_all else 1):
        r.ue(), r.ue(), r.ue()  # max_dec_pic_buffering_minus1, max_num_reorder_pics, max_latency_increase_plus1
    for _ in range(6):  # coding / transform block sizes, transform hierarchy depths
        r.ue()
    if r.u(1) and r.u(1):  # scaling_list_enabled_flag, sps_scaling_list_data_present_flag
        _skip_hevc_scaling_list_data(r)
    r.skip(2)  # amp_enabled_flag, sample_adaptive_offset_enabled_flag
    if r.u(1):  # pcm_enabled_flag
        r.skip(8)
        r.ue(), r.ue()
        r.skip(1)
    num_delta_pocs: list[int] = []
    for i in range(_check(r.ue(), 64, "num_short_term_ref_pic_sets")):
        _skip_st_ref_pic_set(r, i, num_delta_pocs)
    if r.u(1):  # long_term_ref_pics_present_flag
        for _ in range(_check(r.ue(), 32, "num_long_term_ref_pics_sps")):
            r.skip(log2_max_poc_lsb + 1)  # lt_ref_pic_poc_lsb_sps, used_by_curr_pic_lt_sps_flag
    r.skip(2)  # sps_temporal_mvp_enabled_flag, strong_intra_smoothing_enabled_flag
    if not r.u(1):  # vui_parameters_present_flag
        return None
    if r.u(1) and r.u(8) == 255:  # aspect_ratio_info_present_flag, aspect_ratio_idc (255: Extended_SAR)
        r.skip(32)
    if r.u(1):  # overscan_info_present_flag
        r.skip(1)
    if r.u(1):  # video_signal_type_present_flag
        r.skip(4)
        if r.u(1):  # colour_description_present_flag
            r.skip(24)
    if r.u(1):  # chroma_loc_info_present_flag
        r.ue(), r.ue()
    r.skip(3)  # neutral_chroma_indication_flag, field_seq_flag, frame_field_info_present_flag
    if r.u(1):  # default_display_window_flag
        r.ue(), r.ue(), r.ue(), r.ue()
    if not r.u(1):  # vui_timing_info_present_flag
        return None
    tick, scale = r.u(32), r.u(32)
    return Fraction(scale, tick) if tick and scale else None


# ----------------------------------------------------------------------------- HEVC levels

HEVC_LEVELS: tuple[tuple[int, int, int], ...] = (
    # general_level_idc (30 x level), MaxLumaPs (samples), MaxLumaSr (samples/s): H.265 Tables A.8 and A.9
    (30, 36864, 552960),            # 1
    (60, 122880, 3686400),          # 2
    (63, 245760, 7372800),          # 2.1
    (90, 552960, 16588800),         # 3
    (93, 983040, 33177600),         # 3.1
    (120, 2228224, 66846720),       # 4
    (123, 2228224, 133693440),      # 4.1
    (150, 8912896, 267386880),      # 5
    (153, 8912896, 534773760),      # 5.1
    (156, 8912896, 1069547520),     # 5.2
    (180, 35651584, 1069547520),    # 6
    (183, 35651584, 2139095040),    # 6.1
    (186, 35651584, 4278190080),    # 6.2
)
HEVC_LEVEL_UNCONSTRAINED = 255
"""general_level_idc 255, level 8.5: no limits (what x265 writes for lossless streams)."""
_HEVC_MIN_CB = 8  # x265's minimum coding block: the coded picture is a multiple of it


def hevc_level_idc(width: int, height: int, fps: float) -> int:
    """general_level_idc of the lowest level whose limits fit ``width`` x ``height`` at ``fps``.

    The limits checked are those a picture size and rate decide (H.265 A.4.1, A.4.2): the
    coded picture (the size rounded up to the minimum coding block of 8) within MaxLumaPs,
    its width and height within sqrt(8 MaxLumaPs), and its luma sample rate within
    MaxLumaSr.  The bit-rate and compression-ratio limits (MaxBR, MinCR) depend on the
    coded data and are not checked.  255 (level 8.5) when no level up to 6.2 fits.
    """
    if width <= 0 or height <= 0 or not fps > 0:
        raise ValueError(f"HEVC level: no level for {width}x{height} at {fps} frame/s")
    w = -(-width // _HEVC_MIN_CB) * _HEVC_MIN_CB
    h = -(-height // _HEVC_MIN_CB) * _HEVC_MIN_CB
    for idc, max_ps, max_sr in HEVC_LEVELS:
        side = math.sqrt(8 * max_ps)
        if w * h <= max_ps and w <= side and h <= side and w * h * fps <= max_sr:
            return idc
    return HEVC_LEVEL_UNCONSTRAINED


def is_hevc_level(level_idc: int) -> bool:
    """``level_idc`` names a level of Table A.8 (1 to 6.2), not 8.5 (255), 0 or an undefined value."""
    return any(level_idc == idc for idc, _, _ in HEVC_LEVELS)


_HEVC_LEVEL_OFFSET = {32: 15, 33: 12}
"""Offset of general_level_idc in the RBSP of a VPS (after 4 bytes of fields and 11 of profile_tier_level)
and of an SPS (after one byte of fields and 11 of profile_tier_level)."""


def hevc_level_of(nal: bytes) -> int:
    """general_level_idc of an HEVC VPS or SPS NAL unit (with its two-byte header)."""
    t = (nal[0] >> 1) & 0x3F if nal else -1
    if t not in _HEVC_LEVEL_OFFSET:
        raise SdpError(f"not an HEVC VPS or SPS NAL unit ({nal[:4].hex()})")
    rbsp = nal_to_rbsp(nal[2:])
    if len(rbsp) <= _HEVC_LEVEL_OFFSET[t]:
        raise SdpError(f"HEVC {'VPS' if t == 32 else 'SPS'} truncated before general_level_idc")
    return rbsp[_HEVC_LEVEL_OFFSET[t]]


def set_hevc_level(nal: bytes, level_idc: int) -> bytes:
    """An HEVC VPS or SPS NAL unit with general_level_idc set to ``level_idc`` (every other bit as it was;
    emulation prevention redone)."""
    if not 0 <= level_idc <= 255:
        raise ValueError(f"HEVC general_level_idc: {level_idc} is not a byte")
    hevc_level_of(nal)  # checks the type and length
    offset = _HEVC_LEVEL_OFFSET[(nal[0] >> 1) & 0x3F]
    rbsp = bytearray(nal_to_rbsp(nal[2:]))
    rbsp[offset] = level_idc
    return bytes(nal[:2]) + rbsp_to_nal(bytes(rbsp))
