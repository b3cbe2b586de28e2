"""Codecs: H.264/HEVC video through PyAV, metadata (msgpack + zstd)."""

from .meta import pack_meta, unpack_meta
from .video import EncodedFrame, VideoCodecConfig, VideoDecoder, VideoEncoder, contains_idr, iter_nal_units

__all__ = ["EncodedFrame", "VideoCodecConfig", "VideoDecoder", "VideoEncoder", "contains_idr", "iter_nal_units", "pack_meta", "unpack_meta"]
