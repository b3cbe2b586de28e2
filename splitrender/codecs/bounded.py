"""Decompression that never allocates more than a stated limit (zstd bombs).

Every zstd stream a peer sends us goes through :func:`bounded_zstd_decompress`: the
frame's declared content size is checked against the limit *before* anything is
allocated (zstandard allocates the declared size whatever ``max_output_size`` says),
and a frame without a declared size is decompressed in chunks with a hard cap and a
window no larger than the limit.  Used by the metadata codec, the BC4 depth stream and
any later ``data`` stream.
"""

from __future__ import annotations


import zstandard

from ..errors import CodecError

__all__ = ["STREAM_CHUNK", "bounded_zstd_decompress"]

STREAM_CHUNK = 32
"""Input bytes fed per step when a frame does not declare its content size."""
_MIN_WINDOW_LOG = 10  # zstd's smallest window, 1 KiB
_MAX_WINDOW_LOG = 27  # zstd's default decoder limit, 128 MiB


def bounded_zstd_decompress(data: bytes | bytearray | memoryview, limit: int, what: str,
                            exact: int | None = None) -> bytes:
    """Decompress the first zstd frame of ``data`` into at most ``limit`` bytes.

    ``what`` names the stream in error messages (``"metadata"``, ``"bc4"``).  With
    ``exact`` the output must be exactly that many bytes (checked against the
    declared size before decompressing too).  Raises :class:`CodecError` (never
    ``MemoryError``) for anything that is not a frame within the limit.
    """
    if exact is not None:
        limit = min(limit, exact)
    raw = bytes(data)
    try:
        params = zstandard.get_frame_parameters(raw)
    except zstandard.ZstdError as exc:
        raise CodecError(f"{what}: not a zstd frame: {exc}") from None
    declared = params.content_size
    if declared != zstandard.CONTENTSIZE_UNKNOWN:
        if declared > limit:
            raise CodecError(f"{what}: zstd frame declares {declared} bytes, over the limit of {limit}")
        if exact is not None and declared != exact:
            raise CodecError(f"{what}: zstd frame declares {declared} bytes, expected {exact}")
        try:
            # With a declared size zstd writes into a buffer of exactly that size (now
            # known to be within the limit) and fails if the frame would produce more.
            out = zstandard.ZstdDecompressor().decompress(raw, max_output_size=limit)
        except zstandard.ZstdError as exc:
            raise CodecError(f"{what}: zstd: {exc}") from None
        except MemoryError:
            raise CodecError(f"{what}: out of memory decompressing {declared} bytes") from None
    else:
        out = _stream(raw, limit, what, params.window_size)
    if len(out) > limit:  # cannot happen with the checks above; kept as the last word
        raise CodecError(f"{what}: {len(out)} bytes decompressed exceeds the limit of {limit}")
    if exact is not None and len(out) != exact:
        raise CodecError(f"{what}: decompressed to {len(out)} bytes, expected {exact}")
    return out


def _stream(raw: bytes, limit: int, what: str, window: int) -> bytes:
    """Decompress a frame without a declared size, fed :data:`STREAM_CHUNK` input bytes at
    a time, and stop as soon as the output passes ``limit``.

    One step can produce at most a few zstd blocks (128 KiB each, the block size is
    capped by the window, which is capped by ``limit``), so the overshoot before the
    refusal is bounded too."""
    log = min(max((max(limit, 1) - 1).bit_length(), _MIN_WINDOW_LOG), _MAX_WINDOW_LOG)
    if window > 1 << log:
        raise CodecError(f"{what}: zstd window of {window} bytes exceeds the {1 << log}-byte limit")
    parts: list[bytes] = []
    total = 0
    try:
        dobj = zstandard.ZstdDecompressor(max_window_size=1 << log).decompressobj()
        for pos in range(0, len(raw), STREAM_CHUNK):
            chunk = dobj.decompress(raw[pos:pos + STREAM_CHUNK])
            total += len(chunk)
            if total > limit:
                raise CodecError(f"{what}: zstd frame decompresses to more than the limit of {limit} bytes")
            parts.append(chunk)
            if dobj.eof:
                break
    except zstandard.ZstdError as exc:
        raise CodecError(f"{what}: zstd: {exc}") from None
    except MemoryError:
        raise CodecError(f"{what}: out of memory decompressing a frame of undeclared size") from None
    if not dobj.eof:
        raise CodecError(f"{what}: zstd frame is truncated")
    return b"".join(parts)
