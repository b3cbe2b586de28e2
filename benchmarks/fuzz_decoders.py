"""Mutation fuzzing of every untrusted-input entry point, from valid seeds.

Each entry point gets real seeds and is fed ``N`` inputs made by 1-3 mutations each.
Byte inputs get bit flips, interesting bytes, truncation, splices with another seed,
length-field inflation (1/2/4/8-byte fields set to huge values, big- and
little-endian), chunk insertion, deletion and duplication; metadata entry points are
fuzzed at both layers (the zstd frame as sent, and the msgpack inside, recompressed with
or without a declared content size); control frames also get their messages' fields
mutated (:func:`message_mutator`), lists of datagrams their packets dropped, duplicated,
reordered or cut (:func:`datagram_mutator`).  Structured inputs (session data, update
envelopes, the decoded values a client half sees) also get structure-aware mutations
(:func:`random_op`): a scalar replaced by an array, by inf/nan/1e300 or a huge integer,
an array zeroed (a zero transform), made singular, cut short or grown (a count that
no longer matches), cast to another wire dtype, a key deleted, values swapped between
fields; and every structured input still goes through the real wire encoding.

Entry points (``--only`` takes name prefixes):

- the decoders of issue 16: ``unpack_meta``, ``warp``/``sas`` metadata, BC4,
  ``connection.*``, RTP/RTCP, H.264/H.265 depayloading, jitter buffers, SDP, the video
  decoders;
- per method (``video atw warp sas tss quads probes``), from seeds captured in a short
  virtual-time session of that method (:mod:`fuzz_seeds`): ``session.<m>`` the session
  data as the client half receives it (``unpack_meta`` then the half's constructor; an
  accepted one must then take the session's valid updates and render); ``frame.<m>`` the
  update envelope (``pipeline.wire.parse_envelope``), then the client half's ``apply``
  and one ``render``, mutating the envelope msgpack, the decoded values, the data
  payloads and the decoded planes; after a documented error the valid update must
  still apply and render finite pixels; ``client.control.<m>`` the session's control
  frames (``DataChunk``, ``FrameMeta``) into a ``ClientConnection`` and the client
  session core; ``client.datagrams.<m>`` its RTP, FEC and RTCP datagrams into the
  client session core (jitter buffers, FEC recovery, depayloading, decoding);
- ``client.welcome``: the ``Welcome`` and session data as a client takes them;
- ``server.control``: client control frames (``Feedback``, ``Pose``, ``KeyframeRequest``,
  ``Stats``, ``Bye``) into a ``ServerConnection`` and the server session core's
  ``receive_message`` (poses also into the live server's predictor); ``server.rtcp``:
  client RTCP into ``receive_datagram`` (the one RTCP entry), after the live server's routing by SSRC
  (``rtcp_route_ssrc``), with a retransmission history to answer NACKs;
- ``fec.parse``, ``fec.recover`` (an FEC packet and its group but one), ``jitter.fec.*``
  (media and FEC packets through a jitter buffer); their mutations include FEC packets
  whose protection is shorter than a media payload;
- ``server.feedback_flood``: valid ``Feedback`` messages naming random streams, one
  server session core for all of them; the core's retained memory is measured at a
  quarter of the run and at its end, and growth that does not level off is a finding
  (``UnboundedGrowth``).

The rule (h11's): an input either decodes or raises the entry point's documented error
class.  Anything else is reported with a minimal reproducer (greedy chunk deletion that
keeps the exception type, in hex; for structured inputs, greedy removal of mutations,
shown as the seed and the mutations left).  Also reported: inputs per second of wall
time and of this process's CPU time (the one to compare on a shared machine), worst time
per input (as measured, and the slowest 20 inputs re-timed best-of-3, since one timing
on a shared machine includes preemption; with that input), and the peak RSS during the
entry point's run above the RSS at its start (the peak mark is reset through
``/proc/self/clear_refs`` on Linux).

Run: ``python benchmarks/fuzz_decoders.py [--inputs N] [--slow-inputs M] [--only a,b]``
(``--slow-inputs``: the video decoders and the entry points that render: ``frame.*`` and
``session.probes``).  Writes ``benchmarks/results/fuzz_decoders.json`` (with ``--only``,
prints it).
"""

from __future__ import annotations

import argparse
import contextlib
import copy
import heapq
import json
import logging
import math
import platform
import random
import resource
import struct
import sys
import time
import traceback
import types
import warnings
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import msgpack
import numpy as np
import zstandard

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout
sys.path.insert(1, str(Path(__file__).resolve().parent))       # fuzz_seeds, from anywhere

from fuzz_seeds import METHODS, MethodSeeds, capture  # noqa: E402

from splitrender.codecs.depth import bc4_decode, bc4_encode, quantize_depth  # noqa: E402
from splitrender.codecs.meta import pack_meta, parse_update_envelope, unpack_meta  # noqa: E402
from splitrender.errors import CodecError, RemoteProtocolError, ServerRefusedError  # noqa: E402
from splitrender.protocol import (  # noqa: E402
    NEED_DATA,
    Bye,
    ClientConnection,
    Error,
    Feedback,
    FrameMeta,
    GenericNack,
    Hello,
    JitterBuffer,
    KeyframeRequest,
    PictureLossIndication,
    Pose,
    ReceiverReport,
    ReportBlock,
    RtpPacket,
    RtpPacketizer,
    SenderReport,
    ServerConnection,
    Stats,
    StreamDescription,
    Welcome,
    encode_frame,
    h264_depayload,
    h265_depayload,
    make_sdp,
    parameter_sets_from_sdp,
    parse_fmtp,
    parse_rtcp,
    serialize_rtcp,
)
from splitrender.protocol.messages import MAX_LIST_LEN, MAX_LOST_REPORTED, MAX_NAME_LEN, PROTOCOL_VERSION  # noqa: E402

logger = logging.getLogger("fuzz_decoders")
RESULTS = Path(__file__).resolve().parent / "results" / "fuzz_decoders.json"
W, H = 64, 36
HEX_MAX = 4096  # hex characters of a reproducer kept in the report
REPR_MAX = 4096  # characters of a structured reproducer kept in the report
MINIMIZE_TRIES = 3000
SLOWEST_KEPT = 20
"""The slowest inputs are timed again after the run (best of 3): on a shared machine a
single timing includes preemption, so the re-timed worst is the number to trust."""
MB = 1024 * 1024


# ---------------------------------------------------------------------------- mutation
INTERESTING_BYTES = (0x00, 0x01, 0x7F, 0x80, 0xFF, 0xC1, 0xDD, 0xDF, 0xC6, 0xC9)
INFLATE_VALUES = (2**7, 2**8 - 1, 2**15, 2**16 - 1, 2**31 - 1, 2**31, 2**32 - 1, 2**40, 2**63 - 1, 2**63, 2**64 - 1)


def mutate(data: bytes, seeds: list[bytes], rng: random.Random) -> bytes:
    """1-3 random mutations of ``data`` (see the module docstring)."""
    b = bytearray(data)
    for _ in range(rng.randint(1, 3)):
        op = rng.randrange(8)
        n = len(b)
        if op == 0 and n:  # bit flips
            for _ in range(rng.randint(1, 8)):
                i = rng.randrange(n * 8)
                b[i // 8] ^= 1 << (i % 8)
        elif op == 1 and n:  # interesting bytes
            for _ in range(rng.randint(1, 4)):
                b[rng.randrange(n)] = rng.choice(INTERESTING_BYTES)
        elif op == 2:  # truncation
            del b[rng.randint(0, n):]
        elif op == 3:  # splice with another seed
            other = rng.choice(seeds)
            i, j = sorted((rng.randint(0, len(other)), rng.randint(0, len(other))))
            k = rng.randint(0, n)
            b[k:rng.randint(k, n)] = other[i:j]
        elif op == 4 and n:  # length-field inflation
            width = rng.choice((1, 2, 4, 8))
            pos = rng.randint(0, max(0, n - width))
            v = rng.choice(INFLATE_VALUES) & ((1 << (8 * width)) - 1)
            b[pos:pos + width] = v.to_bytes(width, rng.choice(("big", "little")))
        elif op == 5:  # insert random bytes
            k = rng.randint(0, n)
            b[k:k] = bytes(rng.randrange(256) for _ in range(rng.randint(1, 16)))
        elif op == 6 and n:  # delete a chunk
            i = rng.randrange(n)
            del b[i:i + rng.randint(1, 32)]
        elif op == 7 and n:  # duplicate a chunk
            i = rng.randrange(n)
            j = min(n, i + rng.randint(1, 64))
            b[j:j] = b[i:j] * rng.randint(1, 4)
    return bytes(b)


# ---------------------------------------------------------------------------- structure-aware mutation
class _Delete:
    def __repr__(self) -> str:
        return "DELETE"


DELETE = _Delete()
"""An :class:`Op` value: remove the key or list element at the path."""
WIRE_DTYPES = ("|u1", "|i1", "<u2", "<i2", "<u4", "<i4", "<u8", "<i8", "<f2", "<f4", "<f8", "|b1")
"""The dtypes ``pack_meta`` carries (a mutated array stays encodable)."""
SPECIAL_FLOATS = (math.inf, -math.inf, math.nan, 1e300, -1e300, 3.5e38, -0.0, 0.0, 1e-310, 2.0**53)
SPECIAL_INTS = (0, 1, -1, 2, 255, 256, 65535, 65536, 2**31 - 1, 2**31, 2**32, 2**53 + 1, 2**63 - 1, -(2**63), 2**64 - 1)
MAX_CONTAINER_WALK = 64
"""Children of one list or map a mutation may target (the first ones)."""
MAX_GROWN_ELEMENTS = 1 << 16


@dataclass(frozen=True, eq=False)
class Op:
    """One structured mutation: the node at ``path`` becomes ``value`` (or is deleted)."""

    path: tuple[Any, ...]
    value: Any
    why: str

    def __repr__(self) -> str:
        where = "/".join(str(p) for p in self.path) or "<root>"
        return f"{where} <- {self.why}: {show_value(self.value)}"


def show_value(v: Any, limit: int = 160) -> str:
    """A short description of a (possibly large) value for a report."""
    if isinstance(v, np.ndarray):
        if v.size <= 16:
            body = np.array2string(v.reshape(-1), precision=6, separator=",", threshold=16)
        else:
            flat = v.reshape(-1)
            body = f"[{', '.join(repr(x.item()) for x in flat[:4])}, ... {flat[-1].item()!r}]"
        return f"array({v.dtype.str} {v.shape} {body})"
    if isinstance(v, (bytes, bytearray)):
        return f"bytes[{len(v)}] {bytes(v[:48]).hex()}{'...' if len(v) > 48 else ''}"
    if isinstance(v, dict):
        inner = ", ".join(f"{k!r}: {show_value(x, 40)}" for k, x in list(v.items())[:8])
        return "{" + inner + (", ..." if len(v) > 8 else "") + "}"[:limit]
    if isinstance(v, list):
        inner = ", ".join(show_value(x, 40) for x in v[:8])
        return f"[{inner}{', ...' if len(v) > 8 else ''}] (len {len(v)})"[:limit]
    r = repr(v)
    return r if len(r) <= limit else r[:limit - 3] + "..."


def tree_paths(tree: Any) -> list[tuple[Any, ...]]:
    """Paths of every node of an unpacked msgpack tree (the root is ``()``)."""
    out: list[tuple[Any, ...]] = []

    def walk(v: Any, path: tuple[Any, ...], depth: int) -> None:
        out.append(path)
        if depth > 16:
            return
        if isinstance(v, dict):
            for k in list(v)[:MAX_CONTAINER_WALK]:
                walk(v[k], path + (k,), depth + 1)
        elif isinstance(v, list):
            for i, c in enumerate(v[:MAX_CONTAINER_WALK]):
                walk(c, path + (i,), depth + 1)

    walk(tree, (), 0)
    return out


def get_at(tree: Any, path: tuple[Any, ...]) -> Any:
    for p in path:
        tree = tree[p]
    return tree


def apply_ops(tree: Any, ops: tuple[Op, ...]) -> Any:
    """``tree`` (changed in place where it can be) with ``ops`` applied in order; an op whose path
    no longer exists (an earlier op removed it) is skipped."""
    for op in ops:
        if not op.path:
            if op.value is not DELETE:
                tree = copy.deepcopy(op.value)
            continue
        try:
            parent = get_at(tree, op.path[:-1])
            key = op.path[-1]
            if op.value is DELETE:
                del parent[key]
            elif isinstance(parent, dict) or (isinstance(parent, list) and isinstance(key, int)
                                              and -len(parent) <= key < len(parent)):
                parent[key] = copy.deepcopy(op.value)
        except (KeyError, IndexError, TypeError):
            continue
    return tree


def _clip_int(v: int) -> int:
    return max(-(2**63), min(2**64 - 1, v))


def _mutate_array(a: np.ndarray, rng: random.Random) -> tuple[str, Any]:
    kinds = ["special", "special", "zero", "count-", "count+", "empty", "dtype", "flat", "axis", "scalar", "list",
             "scale", "noise", "transpose"]
    if a.ndim >= 2 and a.shape[-2:] == (4, 4):
        kinds += ["singular", "singular", "projective"]
    k = rng.choice(kinds)
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore")
        if k == "special" and a.size:
            b = a.copy()
            flat = b.reshape(-1)
            for _ in range(rng.randint(1, 3)):
                i = rng.randrange(flat.size)
                if b.dtype.kind == "f":
                    flat[i] = rng.choice(SPECIAL_FLOATS)
                elif b.dtype.kind in "ui":
                    info = np.iinfo(b.dtype)
                    flat[i] = rng.choice((info.max, info.min, 0, info.max // 2 + 1))
                else:
                    flat[i] = not flat[i]
            return "element special", b
        if k == "zero":
            return "zeroed", np.zeros_like(a)
        if k == "count-" and a.ndim and a.shape[0]:
            return "count-", a[:rng.randrange(a.shape[0])].copy()
        if k == "count+" and a.ndim and a.shape[0]:
            reps = rng.choice((1, 2, 7, 1000))
            extra = np.concatenate([a] * reps)[: max(1, MAX_GROWN_ELEMENTS // max(1, a[0].size))]
            return "count+", np.concatenate([a, extra])
        if k == "empty":
            return "empty", a[:0].copy() if a.ndim else np.zeros(0, a.dtype)
        if k == "dtype":
            dt = rng.choice(WIRE_DTYPES)
            return f"astype {dt}", a.astype(dt)
        if k == "flat":
            return "flattened", a.reshape(-1).copy()
        if k == "axis":
            return "extra axis", a[None].copy()
        if k == "scalar":
            return "array->scalar", a.reshape(-1)[0].item() if a.size else 0
        if k == "list" and a.size <= 256:
            return "array->list", a.tolist()
        if k == "scale" and a.dtype.kind == "f":
            return "scaled 1e30", a * rng.choice((1e30, -1e30, 1e-30))
        if k == "noise" and a.size:
            g = np.random.default_rng(rng.randrange(2**32))
            if a.dtype.kind == "f":
                return "noise", (g.standard_normal(a.shape) * 10.0 ** g.integers(-3, 8)).astype(a.dtype)
            if a.dtype.kind in "ui":
                info = np.iinfo(a.dtype)
                return "noise", g.integers(info.min, info.max, a.shape, dtype=a.dtype, endpoint=True)
        if k == "transpose" and a.ndim >= 2:
            return "transposed", np.ascontiguousarray(np.swapaxes(a, -1, -2))
        if k in ("singular", "projective"):
            b = a.astype(np.float64) if a.dtype.kind != "f" else a.copy()
            if k == "singular":
                b[..., rng.randrange(3), :3] = 0.0
                return "singular 4x4", b.astype(a.dtype)
            b[..., 3, :] = (0.0, 0.0, 1.0, 0.0)
            return "projective 4x4", b.astype(a.dtype)
    return "zeroed", np.zeros_like(a)


def _mutate_scalar(v: Any, rng: random.Random) -> tuple[str, Any]:
    if isinstance(v, bool):
        return rng.choice((("flipped", not v), ("bool->int", int(v)), ("bool->str", "true"), ("bool->array", np.array([v]))))
    if isinstance(v, int):
        k = rng.randrange(6)
        if k == 0:
            return "special int", rng.choice(SPECIAL_INTS)
        if k == 1:
            return "special float", rng.choice(SPECIAL_FLOATS)
        if k == 2:
            return "scalar->array", rng.choice((np.array([v], np.int64 if -(2**63) <= v < 2**63 else np.uint64),
                                                np.full((2, 2), float(v)), np.zeros(0, np.int64)))
        if k == 3:
            return "off by one", _clip_int(v + rng.choice((-1, 1)))
        if k == 4:
            return "scaled", _clip_int(v * rng.choice((2, 1000, 2**20, -1)))
        return "int->float", float(v)
    if isinstance(v, float):
        k = rng.randrange(5)
        if k <= 1:
            return "special float", rng.choice(SPECIAL_FLOATS)
        if k == 2:
            return "scalar->array", rng.choice((np.array([v]), np.full((3,), v), np.full((4, 4), v, np.float32)))
        if k == 3 and math.isfinite(v):
            return "float->int", _clip_int(int(v))
        return "negated/scaled", v * rng.choice((-1.0, 1e30, 1e-30))
    if isinstance(v, str):
        return rng.choice((("empty str", ""), ("long str", "x" * rng.choice((65, 1025, 70000))), ("str->int", 0),
                           ("other str", rng.choice(("lossless", "bc4", "reference", "residual", "centred", "a\x00b", "é")))))
    if isinstance(v, (bytes, bytearray)):
        if rng.random() < 0.7 and v:
            return "bytes mutated", mutate(bytes(v), [bytes(v)], rng)
        return rng.choice((("empty bytes", b""), ("bytes->str", "x"), ("bytes doubled", bytes(v) * 2)))
    if v is None:
        return rng.choice((("None->0", 0), ("None->list", []), ("None->map", {}), ("None->str", "")))
    return "->None", None


def _mutate_container(v: Any, rng: random.Random) -> tuple[str, Any]:
    if isinstance(v, dict):
        k = rng.randrange(5)
        if k == 0:
            return "map->empty", {}
        if k == 1:
            return "map->list", list(v.values())
        if k == 2:
            w = dict(v)
            w[rng.choice(("zz", "v", "", "x" * 70, 7))] = rng.choice((0, -1, 1e300, "x", None, [], {}, np.zeros(3)))
            return "extra key", w
        if k == 3 and v:
            w = dict(v)
            del w[rng.choice(list(w))]
            return "key dropped", w
        return "map->None", None
    assert isinstance(v, list)
    k = rng.randrange(7)
    if k == 0:
        return "list->empty", []
    if k == 1 and v:
        return "count-", v[:rng.randrange(len(v))]
    if k == 2 and v:
        return "count+", v + v[: rng.randint(1, len(v))]
    if k == 3 and v and all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in v):
        return "list->array", np.array(v, np.float64)
    if k == 4:
        return "nested", [v]
    if k == 5 and len(v) > 1:
        return "reversed", v[::-1]
    return "list->map", {str(i): x for i, x in enumerate(v[:8])}


def random_op(tree: Any, rng: random.Random, prefer: tuple[Any, ...] = ()) -> Op:
    """One structure-aware mutation of ``tree`` (not applied); paths under ``prefer`` are chosen 80% of the time."""
    paths = tree_paths(tree)
    pref = [p for p in paths if prefer and p[:len(prefer)] == prefer and len(p) > len(prefer)]
    path = rng.choice(pref if pref and rng.random() < 0.8 else paths)
    v = get_at(tree, path)
    r = rng.random()
    if r < 0.07 and len(paths) > 1:
        other = get_at(tree, rng.choice(paths))
        return Op(path, copy.deepcopy(other), "value of another field")
    if r < 0.12 and path:
        return Op(path, DELETE, "deleted")
    if isinstance(v, np.ndarray):
        why, new = _mutate_array(v, rng)
    elif isinstance(v, (dict, list)):
        why, new = _mutate_container(v, rng)
    else:
        why, new = _mutate_scalar(v, rng)
    return Op(path, new, why)


def random_ops(tree: Any, rng: random.Random, prefer: tuple[Any, ...] = (), most: int = 3) -> tuple[Op, ...]:
    """1-``most`` ops, each drawn from the tree as the previous ones left it."""
    ops: list[Op] = []
    t = copy.deepcopy(tree)
    for _ in range(rng.randint(1, most)):
        op = random_op(t, rng, prefer)
        ops.append(op)
        t = apply_ops(t, (op,))
    return tuple(ops)


# ---------------------------------------------------------------------------- entry points
@dataclass
class EntryPoint:
    """``run(data)`` decodes one input; ``expected`` is what it may raise."""

    name: str
    seeds: list[Any]
    run: Callable[[Any], Any]
    expected: tuple[type[BaseException], ...]
    slow: bool = False
    encode: Callable[[bytes, random.Random], bytes] | None = None
    """Applied after mutating (the msgpack layer is mutated, then compressed)."""
    mutate: Callable[[Any, list[Any], random.Random], Any] | None = None
    """Makes one input from a seed (default: :func:`mutate` of bytes)."""
    shrink: Callable[[Any], Iterator[Any]] | None = None
    """Smaller candidates of a structured input, for the reproducer (default: chunk deletion of bytes)."""
    show: Callable[[Any], str] | None = None
    """A structured input as text for the report (default: hex)."""
    start: Callable[[int], None] | None = None
    """Called with the number of inputs before the first one."""
    finish: Callable[[], list[Finding]] | None = None
    """Findings about the run as a whole (e.g. memory that kept growing), after the last input."""
    notes: dict[str, Any] = field(default_factory=dict)
    """Numbers an entry point reports besides the standard ones."""


@dataclass
class Finding:
    type: str
    message: str
    count: int = 0
    smallest: Any = b""
    where: str = ""


class HarnessFinding(Exception):
    """Raised by an entry point's ``run`` for a failure that is not an exception of the code under test
    (a state it left broken, non-finite pixels, memory growth); never in ``expected``."""


class StateCorrupted(HarnessFinding):
    """After a documented error the client half did not take the valid update it took before."""


class RenderFailed(HarnessFinding):
    """``render`` raised (any exception: the drivers do not catch render errors)."""


class BadFrame(HarnessFinding):
    """``render`` returned something that is not a finite (H, W, 3) image."""


class AfterSessionData(HarnessFinding):
    """Session data the client half accepted made a valid update fail with an undocumented error."""


class UnboundedGrowth(HarnessFinding):
    """State kept by a session grew with the number of valid messages."""


class BadPrediction(HarnessFinding):
    """Poses the server accepted made its predictor return a non-finite pose."""


class Unencodable(Exception):
    """A structured mutation the wire encoding cannot carry (not an input at all; counted, never a finding)."""


def _zstd(raw: bytes, content_size: bool = True) -> bytes:
    return zstandard.ZstdCompressor(level=1, write_content_size=content_size).compress(raw)


def _zstd_either(raw: bytes, rng: random.Random) -> bytes:
    """zstd with a declared content size, or without (the streaming path)."""
    return _zstd(raw, rng.random() < 0.7)


def _unzstd(blob: bytes) -> bytes:
    return zstandard.ZstdDecompressor().decompressobj().decompress(blob)


def _pack(tree: Any) -> bytes:
    try:
        return pack_meta(tree)
    except (CodecError, TypeError, ValueError, OverflowError) as exc:
        raise Unencodable(str(exc)[:200]) from None


def _split_lp(data: bytes) -> list[bytes]:
    """Inverse of :func:`_join_lp`: 2-byte big-endian length-prefixed chunks (stops at a short one)."""
    out, pos = [], 0
    while pos + 2 <= len(data):
        (n,) = struct.unpack_from(">H", data, pos)
        out.append(data[pos + 2:pos + 2 + n])
        pos += 2 + n
    return out


def _join_lp(chunks: list[bytes]) -> bytes:
    return b"".join(struct.pack(">H", len(c)) + c for c in chunks)


_SEEDS: dict[str, MethodSeeds] = {}
_RENDERER: list[Any] = []


def method_seeds(method: str, renderer: Any = None) -> MethodSeeds:
    """The seeds of ``method``'s short session (captured once per process, :func:`fuzz_seeds.capture`)."""
    if method not in _SEEDS:
        if renderer is None:
            if not _RENDERER:
                from splitrender.render.renderer import Renderer

                _RENDERER.append(Renderer())
            renderer = _RENDERER[0]
        t0 = time.perf_counter()
        _SEEDS[method] = capture(method, renderer=renderer)
        logger.info("seeds of %s captured in %.1f s", method, time.perf_counter() - t0)
    return _SEEDS[method]


_GL: list[Any] = []


def client_gl() -> Any:
    """The GL context the fuzzed client halves share (EGL, llvmpipe on a CPU), made current.

    Objects of dropped halves are queued (``gc_mode = "context_gc"``) and released by
    :func:`release_gl_garbage` while this context is current, never on another context."""
    from splitrender.render.gl import create_context, make_current

    if not _GL:
        ctx = create_context()
        ctx.gc_mode = "context_gc"
        _GL.append(ctx)
    return make_current(_GL[0])


def release_gl_garbage() -> None:
    """Release the GL objects of dropped halves (``ctx.gc()`` without its failure on objects a half had
    already released itself, which moderngl queues as ``InvalidObject``)."""
    if _GL:
        objs = client_gl().objects
        while objs:
            release = getattr(objs.popleft(), "release", None)
            if release is not None:
                release()


# ---------------------------------------------------------------------------- issue 16 entry points
def _encode_aus(codec: str, n: int = 6) -> list[bytes]:
    from splitrender.codecs.video import VideoCodecConfig, VideoEncoder

    enc = VideoEncoder(VideoCodecConfig(codec=codec, gop=3), W, H)  # type: ignore[arg-type]
    rng = np.random.default_rng(1)
    img = rng.integers(0, 256, (H, W * 2, 3), dtype=np.uint8)
    aus = []
    for i in range(n):
        ef = enc.encode(np.ascontiguousarray(img[:, 4 * i:4 * i + W]), force_idr=i == 0)
        aus.append(bytes(ef.data))
    return [a for a in aus if a]


def _warp_seed() -> tuple[bytes, Callable[[bytes], Any]]:
    from splitrender.methods.base import DecodedUpdate
    from splitrender.methods.warp import META_VERSION, WarpConfig, parse_update
    from splitrender.scene.pose import CameraIntrinsics
    from splitrender.scene.pose import Pose as ScenePose

    intr = CameraIntrinsics(W, H, 60.0)
    cfg = WarpConfig(views=1, depth_coding="bc4")
    pose = [0.0, 1.6, 2.5, 0.0, 0.0, 0.0, 1.0]
    depth = np.linspace(1.0, 20.0, W * H).reshape(H, W)
    depth[:4] = np.inf
    m = {"v": META_VERSION, "depth_coding": "bc4", "depth_near_m": 0.1, "ref": [W, H, 60.0],
         "views": [{"pose": pose, "ids": (np.arange(W * H) % 3).reshape(H, W).astype(np.uint8),
                    "bc4": bc4_encode(quantize_depth(depth, 0.1))}],
         "obj_ids": np.array([1, 2], np.uint16), "obj_model": np.tile(np.eye(4), (2, 1, 1)),
         "dyn_ids": np.array([2], np.uint16), "dyn_prev": np.eye(4)[None], "dt_s": 1 / 30}
    blob = pack_meta({"t_s": 1.0, "pose": pose, "m": m, "target_t_s": 1.05,
                      "timing_us": {"render": 900, "encode": 700, "encoded_at": 1_700_000_000_000_000},
                      "srv": {"views": 1.0, "objects": 2.0, "bc4_bytes": 300.0}})
    color = np.zeros((H, W, 3), np.uint8)

    def run(data: bytes) -> Any:
        env = parse_update_envelope(unpack_meta(data))
        return parse_update(DecodedUpdate(0, env["t_s"], ScenePose.from_list(env["pose"]), {"color0": color},
                                          env["m"]), cfg, intr)

    run(blob)
    return blob, run


def _sas_seeds() -> tuple[bytes, bytes, Callable[[bytes], Any], Callable[[bytes], Any]]:
    from splitrender.methods.sas.wire import META_VERSION, parse_frame_meta, parse_session

    # seeds from a real sas session: a short virtual-time run, the first update's envelope as sent
    seeds = method_seeds("sas")
    session = parse_session(seeds.session_data)
    frame_blob = seeds.updates[0].meta_blob
    session_blob = seeds.session_blob
    assert META_VERSION == parse_update_envelope(unpack_meta(frame_blob))["m"]["v"]

    def run_frame(data: bytes) -> Any:
        return parse_frame_meta(parse_update_envelope(unpack_meta(data))["m"], session)

    def run_session(data: bytes) -> Any:
        return parse_session(unpack_meta(data))

    run_frame(frame_blob)
    run_session(session_blob)
    return frame_blob, session_blob, run_frame, run_session


def _control_seeds() -> list[bytes]:
    pose = Pose(1_700_000_000_000_000, 7, (0.0, 1.6, 2.5), (0.0, 0.0, 0.0, 1.0))
    meta = FrameMeta(5, 1_700_000_000_000_000, {"color": 123456}, pose, pack_meta({"t_s": 1.0, "m": {}}), True)
    welcome = Welcome("sid-1", "warp", {"config": {"views": 2}, "session_data": b"\x00" * 40},
                      (StreamDescription("color", "h264", 0x1234, 96, 5004, make_sdp("h264", 5004, 96)),))
    msgs: list[Any] = [Hello(PROTOCOL_VERSION, "tok", ("warp", "video"), ("h264", "hevc"), 640, 360, 60.0),
                       welcome, pose, meta, Feedback(5, 1, 2, 3, 0, 4, {"render": 1}), KeyframeRequest("color", "loss"),
                       Stats({"fps": 60.0, "lost": 0}), Bye("done"), Error(400, "x" * 1500)]
    frames = [encode_frame(m) for m in msgs]
    frames.append(encode_frame(meta, compress=True))
    frames.append(b"".join(frames[2:5]))  # a stream of several frames
    return frames


def _connection_run(role: str) -> Callable[[bytes], Any]:
    """Feed bytes to a Connection already in STREAMING; on a peer error send an Error."""
    hello = Hello(PROTOCOL_VERSION, "", ("video",), ("h264",), 160, 90, 30.0)

    def run(data: bytes) -> Any:
        c, s = ClientConnection(), ServerConnection()
        s.receive_data(c.send(hello))
        s.next_event()
        c.receive_data(s.send(Welcome("sid", "video")))
        c.next_event()
        conn = c if role == "client" else s
        try:
            step = 1 + len(data) % 97
            for i in range(0, len(data), step):
                conn.receive_data(data[i:i + step])
                while conn.next_event() is not NEED_DATA:
                    pass
            conn.receive_data(b"")
            conn.next_event()
        except RemoteProtocolError as exc:
            conn.send_error(exc)  # must work in every state peer input can reach
            raise

    return run


def _rtp_seeds(codec: str, aus: list[bytes]) -> list[bytes]:
    pk = RtpPacketizer(codec, 0x1234ABCD, 96, mtu=300, first_sequence=65530)  # type: ignore[arg-type]
    return [bytes(p) for i, au in enumerate(aus) for p in pk.packetize(au, i * 3000)]


def _jitter_run(codec: str) -> Callable[[bytes], Any]:
    def run(data: bytes) -> Any:
        jb = JitterBuffer(codec, max_packets=128)  # type: ignore[arg-type]
        now = 0.0
        for raw in _split_lp(data):
            now += 3.0
            try:
                pkt = RtpPacket.parse(raw)
            except RemoteProtocolError:
                continue
            jb.insert(pkt, now)  # malformed payloads are counted, never raised
        jb.poll(now + 1000.0)
        jb.missing()

    return run


def _video_run(codec: str) -> Callable[[bytes], Any]:
    from splitrender.codecs.video import VideoDecoder

    def run(data: bytes) -> Any:
        dec = VideoDecoder(codec, "rgb24")  # type: ignore[arg-type]
        return dec.decode(data)

    return run


# ---------------------------------------------------------------------------- client halves: session data, updates
def _diff(seed: bytes, new: bytes) -> str:
    """``new`` as the bytes of ``seed`` it changed (common prefix and suffix left out), in hex."""
    p = 0
    n = min(len(seed), len(new))
    while p < n and seed[p] == new[p]:
        p += 1
    q = 0
    while q < n - p and seed[len(seed) - 1 - q] == new[len(new) - 1 - q]:
        q += 1
    mid = new[p:len(new) - q]
    return (f"seed[{p}:{len(seed) - q}] ({len(seed) - q - p} bytes) replaced by {len(mid)} bytes "
            f"{mid.hex()[:HEX_MAX]}{'...' if len(mid) * 2 > HEX_MAX else ''} (length {len(seed)} -> {len(new)})")


@dataclass(frozen=True, eq=False)
class TreeCase:
    """Session data: its msgpack as sent, mutated (``raw``), or the unpacked map with ``ops`` applied."""

    raw: bytes | None = None
    ops: tuple[Op, ...] = ()


@dataclass(frozen=True, eq=False)
class FrameCase:
    """Update ``k`` of a captured session, mutated: its envelope msgpack replaced (``env_raw``) or
    changed by ``ops`` (paths from the envelope root: the method's metadata is under ``m``), data
    payloads replaced (decompressed, as the client half sees them), planes replaced (``None``: the
    stream went missing)."""

    k: int
    env_raw: bytes | None = None
    ops: tuple[Op, ...] = ()
    data: tuple[tuple[str, bytes], ...] = ()
    planes: tuple[tuple[str, Any], ...] = ()


def _without(t: tuple[Any, ...], i: int) -> tuple[Any, ...]:
    return t[:i] + t[i + 1:]


def _shrink_tree(c: TreeCase) -> Iterator[TreeCase]:
    if c.raw is not None and c.ops:
        yield replace(c, raw=None)
    for i in range(len(c.ops)):
        yield replace(c, ops=_without(c.ops, i))


def _shrink_frame(c: FrameCase) -> Iterator[FrameCase]:
    if c.env_raw is not None and (c.ops or c.data or c.planes):
        yield replace(c, env_raw=None)
    for i in range(len(c.ops)):
        yield replace(c, ops=_without(c.ops, i))
    for i in range(len(c.data)):
        yield replace(c, data=_without(c.data, i))
    for i in range(len(c.planes)):
        yield replace(c, planes=_without(c.planes, i))


def _mutate_plane(p: np.ndarray | None, rng: random.Random) -> np.ndarray | None:
    """A decoded picture as a hostile stream could make the decoder return it (or ``None``: lost)."""
    if p is None or rng.random() < 0.25:
        return None
    g = np.random.default_rng(rng.randrange(2**32))
    h = p.shape[0]
    k = rng.randrange(8)
    if k == 0:
        return p[: max(2, h - 2 * rng.randint(1, max(1, h // 4)))].copy()
    if k == 1:
        return np.pad(p, ((0, 2 * rng.randint(1, 8)), (0, 0)) + ((0, 0),) * (p.ndim - 2))
    if k == 2:
        return p[..., 0].copy() if p.ndim == 3 else np.stack([p] * 3, -1)
    if k == 3:
        return np.concatenate([p, p[..., :1]], -1) if p.ndim == 3 else p[..., None].copy()
    if k == 4:
        return np.ascontiguousarray(np.swapaxes(p, 0, 1))
    if k == 5:
        return g.integers(0, 256, p.shape, dtype=np.uint8)
    if k == 6:
        return np.zeros((2, 2) + p.shape[2:], np.uint8)
    return np.repeat(np.repeat(p, 2, 0), 2, 1)


def _check_frame(cf: Any, intr: Any, where: str) -> None:
    """A rendered ``ClientFrame`` is an (H, W, 3) image of finite values with an (H, W) hole mask or none."""
    c = getattr(cf, "color", None)
    shape = (intr.height, intr.width, 3)
    if not isinstance(c, np.ndarray) or c.shape != shape or c.dtype.kind not in "uf":
        raise BadFrame(f"{where}: colour {show_value(c)}, expected {shape} pixels")
    if c.dtype.kind == "f" and not np.isfinite(c).all():
        raise BadFrame(f"{where}: {int((~np.isfinite(c)).sum())} non-finite pixel values")
    holes = getattr(cf, "holes", None)
    if holes is not None and (not isinstance(holes, np.ndarray) or holes.shape != shape[:2]):
        raise BadFrame(f"{where}: hole mask {show_value(holes)}, expected {shape[:2]}")


class ClientHalfFuzzer:
    """One method's client half fed mutated session data (:meth:`run_session`) and updates
    (:meth:`run_frame`), from a captured session.

    Updates are stateful (``sas`` and ``tss`` send geometry once, ``quads`` residuals need
    their reference), so update ``k`` is always applied to a half that took the session's
    valid updates ``0 .. k-1`` and nothing else: the half is kept while it stays in that state
    (after a documented error it must: the update is checked before anything changes) and
    rebuilt and replayed when a mutated update was accepted.
    """

    def __init__(self, seeds: MethodSeeds) -> None:
        from splitrender.methods.base import get_method

        self.s = seeds
        self.method = seeds.method
        self.cls = get_method(seeds.method).client_class
        self.updates = seeds.updates
        self.env = [unpack_meta(u.meta_blob) for u in self.updates]
        self.env_raw = [_unzstd(u.meta_blob) for u in self.updates]
        self.session_data = seeds.session_data
        self.session_raw = _unzstd(seeds.session_blob) if seeds.session_blob else b""
        self.data_names = sorted({n for u in self.updates for n in u.update.data})
        self.plane_names = sorted({n for u in self.updates for n in (*u.update.planes, *u.update.missing)} - set(self.data_names))
        self.half: Any = None
        self.pos = 0
        self.dirty = True
        self.rebuilds = 0
        self.sequential = True
        # the valid session, once: which updates the half rejects itself, the first that gives it content
        self.rejected: set[int] = set()
        self.first_content = len(self.updates) - 1
        half = self._new_half(self.session_data)
        for k in range(len(self.updates)):
            try:
                half.apply(self.valid(k))
            except RemoteProtocolError:
                self.rejected.add(k)
            if half.has_content and self.first_content == len(self.updates) - 1:
                self.first_content = k
            self._render(half, k, f"the valid update {k}", own=False)
        half = None
        release_gl_garbage()

    # -------------------------------------------------------------- state
    def _new_half(self, session_data: Any) -> Any:
        return self.cls(self.s.config, self.s.intrinsics, client_gl(), session_data)

    def valid(self, k: int) -> Any:
        """Update ``k`` as the session delivered it (fresh copies: a half may keep what it is given)."""
        from splitrender.methods.base import DecodedUpdate

        u = self.updates[k].update
        return DecodedUpdate(u.frame_id, u.t_s, u.pose, {n: p.copy() for n, p in u.planes.items()},
                             copy.deepcopy(u.meta), dict(u.data), u.missing)

    def _prepare(self, k: int) -> None:
        """``self.half`` in the state of the valid updates ``0 .. k-1`` applied."""
        client_gl()
        if self.half is None or self.dirty or self.pos > k:
            self.half = None
            release_gl_garbage()
            self.half = self._new_half(self.session_data)
            self.pos, self.dirty = 0, False
            self.rebuilds += 1
        while self.pos < k:
            try:
                self.half.apply(self.valid(self.pos))
            except RemoteProtocolError:
                if self.pos not in self.rejected:
                    self.dirty = True
                    raise
            self.pos += 1

    def _render(self, half: Any, k: int, when: str, own: bool = True) -> None:
        """Render once at update ``k``'s pose, 1/60 s after it, as a display tick would; check the picture."""
        if not half.has_content:  # the drivers show the black background until the half has content
            return
        u = self.updates[k].update
        try:
            cf = half.render(u.pose, u.t_s + 1 / 60)
            _check_frame(cf, self.s.intrinsics, f"{self.method}: render after {when}")
        except HarnessFinding:
            self.dirty = self.dirty or own
            raise
        except Exception as exc:
            self.dirty = self.dirty or own
            raise RenderFailed(f"{self.method}: render after {when} raised {type(exc).__name__}: {str(exc)[:300]}") from exc

    # -------------------------------------------------------------- updates
    def build(self, c: FrameCase) -> Any:
        """The ``DecodedUpdate`` the client pipeline would hand the half for ``c`` (the envelope through
        ``parse_envelope``, as ``ClientPipeline`` parses every ``FrameMeta``)."""
        from splitrender.methods.base import DecodedUpdate
        from splitrender.pipeline.receiver import DEFAULT_META_MAX_BYTES
        from splitrender.pipeline.wire import parse_envelope

        if c.env_raw is not None:
            blob = _zstd(c.env_raw)
        elif c.ops:
            blob = _pack(apply_ops(copy.deepcopy(self.env[c.k]), c.ops))
        else:
            blob = self.updates[c.k].meta_blob
        env = parse_envelope(blob, DEFAULT_META_MAX_BYTES)
        u = self.updates[c.k].update
        planes = {n: p.copy() for n, p in u.planes.items()}
        data, missing = dict(u.data), set(u.missing)
        for n, p in c.planes:
            if p is None:
                planes.pop(n, None)
                missing.add(n)
            else:
                planes[n] = p.copy()
                missing.discard(n)
        for n, b in c.data:
            data[n] = b
            missing.discard(n)
        return DecodedUpdate(u.frame_id, env.t_s, env.pose, planes, env.meta, data, frozenset(missing))

    def run_frame(self, c: FrameCase) -> None:
        self._prepare(c.k)
        upd = self.build(c)   # a documented error here: the half never saw the update
        try:
            self.half.apply(upd)
        except RemoteProtocolError as exc:
            self._follow_up(c.k, exc)
            raise
        except BaseException:
            self.dirty = True
            raise
        self.dirty = True     # a mutated update was taken: the state is no longer the session's
        self._render(self.half, c.k, "an accepted mutated update")

    def _follow_up(self, k: int, exc: BaseException) -> None:
        """After a documented error the half still takes the valid update ``k`` and renders it."""
        if k in self.rejected:
            self.dirty = True
            return
        try:
            self.half.apply(self.valid(k))
        except Exception as e2:
            self.dirty = True
            raise StateCorrupted(f"{self.method}: after {type(exc).__name__} ({str(exc)[:200]}), the valid update {k} "
                                 f"(frame {self.updates[k].frame_id}) raised {type(e2).__name__}: {str(e2)[:300]}") from e2
        self.pos = k + 1
        self._render(self.half, k, f"the valid update {k} that followed a rejected one")

    def pick_k(self, rng: random.Random) -> int:
        """Mostly the update that comes next for the current half (no replay), else any."""
        if not self.dirty and self.half is not None and self.pos < len(self.updates) and rng.random() < 0.6:
            return self.pos
        return rng.randrange(len(self.updates))

    def mutate_frame(self, base: FrameCase, seeds: list[Any], rng: random.Random) -> FrameCase:
        """A mutation of an update: of the one after the half's state (:meth:`pick_k`), or with
        ``sequential = False`` of the seed's (the random draws then do not depend on the half's state,
        as hypothesis requires)."""
        k = self.pick_k(rng) if self.sequential else base.k
        u = self.updates[k].update
        kinds = set(rng.choices(("env", "ops", "data", "planes"), weights=(25, 45, 15 if self.data_names else 0, 15),
                                k=1 + (rng.random() < 0.25)))
        env_raw: bytes | None = None
        ops: tuple[Op, ...] = ()
        data: list[tuple[str, bytes]] = []
        planes: list[tuple[str, Any]] = []
        if "env" in kinds:
            env_raw = mutate(self.env_raw[k], self.env_raw, rng)
        elif "ops" in kinds:
            ops = random_ops(self.env[k], rng, prefer=("m",))
        if "data" in kinds and self.data_names:
            name = rng.choice(self.data_names)
            pool = [v.update.data[name] for v in self.updates if name in v.update.data]
            data.append((name, mutate(u.data[name] if name in u.data else rng.choice(pool), pool, rng)))
        if "planes" in kinds and self.plane_names:
            name = rng.choice(self.plane_names)
            planes.append((name, _mutate_plane(u.planes.get(name), rng)))
        return FrameCase(k, env_raw, ops, tuple(data), tuple(planes))

    def show_frame(self, c: FrameCase) -> str:
        fid = self.updates[c.k].frame_id
        parts = [f"{self.method} update {c.k} (frame {fid}), applied after the session's valid updates 0..{c.k - 1}, "
                 f"then rendered at its pose"]
        if c.env_raw is not None:
            parts.append(f"envelope msgpack (zstd-compressed as sent): {_diff(self.env_raw[c.k], c.env_raw)}")
        if c.ops:
            parts.append("envelope changed: " + "; ".join(repr(op) for op in c.ops))
        u = self.updates[c.k].update
        for n, b in c.data:
            seed = u.data.get(n)
            parts.append(f"data[{n}]: " + (_diff(seed, b) if seed is not None else f"{len(b)} bytes {b.hex()[:HEX_MAX]}"))
        for n, p in c.planes:
            parts.append(f"plane {n}: " + ("missing" if p is None else show_value(p)))
        return "\n".join(parts)

    # -------------------------------------------------------------- session data
    def run_session(self, c: TreeCase) -> None:
        from splitrender.pipeline.wire import EnvelopeError

        blob = _zstd(c.raw) if c.raw is not None else _pack(apply_ops(copy.deepcopy(self.session_data), c.ops))
        try:  # as the live client reads the assembled session data
            sd = unpack_meta(blob)
        except CodecError as exc:
            raise EnvelopeError(f"session data: {exc}") from None
        half = self._new_half(sd)
        try:
            for k in range(self.first_content + 1):
                try:
                    half.apply(self.valid(k))
                except RemoteProtocolError:
                    continue
                except Exception as exc:
                    raise AfterSessionData(f"{self.method}: session data accepted, then the valid update {k} raised "
                                           f"{type(exc).__name__}: {str(exc)[:300]}") from exc
            self._render(half, self.first_content, "accepted session data and the valid updates", own=False)
        finally:
            half = None
            release_gl_garbage()

    def mutate_session(self, base: TreeCase, seeds: list[Any], rng: random.Random) -> TreeCase:
        if self.session_raw and rng.random() < 0.4:
            return TreeCase(raw=mutate(self.session_raw, [self.session_raw], rng))
        return TreeCase(ops=random_ops(self.session_data, rng))

    def show_session(self, c: TreeCase) -> str:
        parts = [f"{self.method} session data"]
        if c.raw is not None:
            parts.append(f"msgpack (zstd-compressed as sent): {_diff(self.session_raw, c.raw)}")
        if c.ops:
            parts.append("changed: " + "; ".join(repr(op) for op in c.ops))
        return "\n".join(parts)


def _client_half_entry_points(method: str) -> list[EntryPoint]:
    fz = ClientHalfFuzzer(method_seeds(method))
    slow_session = method == "probes"   # its client draws the whole scene: ~30 ms a render at 160x90 on llvmpipe
    return [
        EntryPoint(f"session.{method}", [TreeCase()], fz.run_session, (RemoteProtocolError,), slow=slow_session,
                   mutate=fz.mutate_session, shrink=_shrink_tree, show=fz.show_session),
        EntryPoint(f"frame.{method}", [FrameCase(k) for k in range(len(fz.updates))], fz.run_frame,
                   (RemoteProtocolError,), slow=True, mutate=fz.mutate_frame, shrink=_shrink_frame, show=fz.show_frame),
    ]


# ---------------------------------------------------------------------------- client session core
def _hello(method: str = "video", codec: str = "h264") -> Hello:
    return Hello(PROTOCOL_VERSION, "", (method,), (codec,), 160, 90, 30.0)


def _drain(conn: Any, data: bytes, step: int) -> Iterator[Any]:
    """The messages ``data`` completes on ``conn``, fed ``step`` bytes at a time, then EOF."""
    from splitrender.protocol import Message

    for i in range(0, len(data), step):
        conn.receive_data(data[i:i + step])
        while isinstance(ev := conn.next_event(), Message):
            yield ev
    conn.receive_data(b"")
    while isinstance(ev := conn.next_event(), Message):
        yield ev


def _client_core(s: MethodSeeds) -> Any:
    from splitrender.pipeline import ClientOptions, ClientSession

    core = ClientSession.from_welcome(s.welcome, ClientOptions(), 0, np.random.default_rng(0))
    core.start(0.0)
    return core


def _decode_all(core: Any, now_ms: float) -> None:
    """Decode what the client core released (``work_to_decode``)."""
    from splitrender.pipeline import ClientPipeline

    for w in core.work_to_decode():
        core.on_decoded(w, ClientPipeline.decode(w), now_ms)


def _client_control_run(s: MethodSeeds) -> Callable[[bytes], Any]:
    """Server control frames into a ``ClientConnection`` past the handshake and the client session core."""
    template = ClientConnection()
    template.send(_hello(s.method, s.config.codec))
    for _ in _drain(template, s.welcome_frame + b"".join(s.session_chunks), 1 << 20):
        pass
    template = ClientConnection()   # the drain above ended with EOF: redo it without
    template.send(_hello(s.method, s.config.codec))
    template.receive_data(s.welcome_frame + b"".join(s.session_chunks))
    while template.next_event() is not NEED_DATA:
        pass

    def run(data: bytes) -> Any:
        conn = copy.deepcopy(template)
        core = _client_core(s)
        now = 0.0
        for msg in _drain(conn, data, 1 + len(data) % 97):
            now += 1.0
            core.receive_message(msg, now)
        now += 1000.0
        core.handle_timer(now)
        _decode_all(core, now)
        return core.display_tick(None, now + 1000.0, hold=False)[1]   # the frames' one way out

    return run


def _client_control_seeds(s: MethodSeeds) -> list[bytes]:
    frames, cur = [], b""
    for msg, data in s.server_frames:
        cur += data
        if isinstance(msg, FrameMeta):
            frames.append(cur)
            cur = b""
    seeds = frames[:16] + [a + b for a, b in zip(frames[:8], frames[1:9])]
    return [x for x in seeds if len(x) < 4 * MB]


def _fec_ssrcs(s: MethodSeeds) -> set[int]:
    return {d.fec_ssrc for d in s.welcome.streams if d.fec_payload_type}


def _by_timestamp(pkts: list[bytes]) -> dict[int, list[bytes]]:
    out: dict[int, list[bytes]] = {}
    for d in pkts:
        out.setdefault(int.from_bytes(d[4:8], "big"), []).append(d)
    return out


def _client_datagram_seeds(s: MethodSeeds) -> list[bytes]:
    """Per frame: every stream's media and FEC packets; again with one media packet per stream lost (the
    last, the short one, or the middle: FEC rebuilds it); the first two frames with a sender report."""
    media: dict[int, list[bytes]] = {}
    fec: dict[int, list[bytes]] = {}
    for name in s.rtp:
        for ts, pk in _by_timestamp(s.rtp[name]).items():
            media.setdefault(ts, []).extend(pk)
        for ts, pk in _by_timestamp(s.fec.get(name, [])).items():
            fec.setdefault(ts, []).extend(pk)
    seeds = []
    tss = sorted(media)
    for i, ts in enumerate(tss[:10]):
        m, f = media[ts], fec.get(ts, [])
        seeds.append(_join_lp(m + f))
        if f and len(m) > 1:
            drop = len(m) - 1 if i % 2 == 0 else len(m) // 2
            seeds.append(_join_lp(m[:drop] + m[drop + 1:] + f))
    if len(tss) > 1:
        seeds.append(_join_lp(media[tss[0]] + fec.get(tss[0], []) + media[tss[1]] + s.rtcp_down[:1]))
    return [x for x in seeds if len(x) < 2 * MB]


def _client_datagram_run(s: MethodSeeds) -> Callable[[bytes], Any]:
    """RTP, FEC and RTCP datagrams into the client session core, every frame it releases decoded."""

    def run(data: bytes) -> Any:
        core = _client_core(s)
        now = 0.0
        for d in _split_lp(data):
            now += 1.0
            core.receive_datagram(d, now)
            _decode_all(core, now)
        now += 1000.0
        core.handle_timer(now)
        _decode_all(core, now)
        return core.datagrams_to_send()

    return run


def shorten_fec(raw: bytes, rng: random.Random) -> bytes:
    """FEC packet ``raw`` with a smaller protection length (the XOR body cut to match): shorter than the
    group's longest media payload unless the cut length happens to cover it."""
    try:
        pkt = RtpPacket.parse(raw)
    except RemoteProtocolError:
        return raw
    p = pkt.payload
    if len(p) < 14:
        return raw
    off = 14 + (4 if p[0] & 0x40 else 0)
    (prot,) = struct.unpack_from("!H", p, 10)
    if prot == 0 or len(p) < off:
        return raw
    new = rng.randrange(prot)
    return bytes(replace(pkt, payload=p[:10] + struct.pack("!H", new) + p[12:off] + p[off:off + new]))


def datagram_mutator(fec_ssrcs: set[int], short_fec: float = 0.15) -> Callable[[bytes, list[bytes], random.Random], bytes]:
    """Mutations of a length-prefixed list of datagrams: of the container's bytes (30%), or of its packets:
    drop, duplicate, swap, splice one from another seed, mutate one's bytes, mutate an FEC header,
    shorten an FEC packet's protection (:func:`shorten_fec`, chosen ``short_fec`` of the time at least)."""

    def mut(data: bytes, seeds: list[bytes], rng: random.Random) -> bytes:
        chunks = _split_lp(data)
        if not chunks or rng.random() < 0.3:
            return mutate(data, seeds, rng)
        for _ in range(rng.randint(1, 2)):
            fec_idx = [i for i, c in enumerate(chunks) if len(c) >= 12 and int.from_bytes(c[8:12], "big") in fec_ssrcs]
            k = rng.randrange(7)
            if fec_idx and (k == 0 or rng.random() < short_fec):
                i = rng.choice(fec_idx)
                chunks[i] = shorten_fec(chunks[i], rng)
            elif k == 1 and chunks:
                del chunks[rng.randrange(len(chunks))]
            elif k == 2 and chunks:
                chunks.insert(rng.randrange(len(chunks) + 1), chunks[rng.randrange(len(chunks))])
            elif k == 3 and len(chunks) > 1:
                i, j = rng.sample(range(len(chunks)), 2)
                chunks[i], chunks[j] = chunks[j], chunks[i]
            elif k == 4 and chunks:
                i = rng.randrange(len(chunks))
                chunks[i] = mutate(chunks[i], chunks, rng)[:65535]
            elif k == 5:
                other = _split_lp(rng.choice(seeds))
                if other:
                    chunks.insert(rng.randrange(len(chunks) + 1), rng.choice(other))
            elif fec_idx:
                i = rng.choice(fec_idx)
                c = chunks[i]
                chunks[i] = (mutate(c[:30], [c[:30]], rng) + c[30:])[:65535]
        return _join_lp(chunks)

    return mut


def _plain(o: Any) -> Any:
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(f"cannot pack {type(o).__name__}")


def split_frames(data: bytes) -> list[tuple[int, Any]] | None:
    """Control frames as (message type, unpacked body), or ``None`` when ``data`` is not a clean sequence of them."""
    from splitrender.protocol.framing import FLAG_ZSTD, HEADER, MAGIC

    out, pos = [], 0
    try:
        while pos < len(data):
            magic, _, mtype, flags, n = HEADER.unpack_from(data, pos)
            body = data[pos + HEADER.size:pos + HEADER.size + n]
            if magic != MAGIC or len(body) != n:
                return None
            if flags & FLAG_ZSTD:
                body = _unzstd(body)
            out.append((mtype, msgpack.unpackb(body, raw=False, strict_map_key=False)))
            pos += HEADER.size + n
    except Exception:  # noqa: BLE001 - not a clean sequence: byte mutations only
        return None
    return out


def message_mutator(p_struct: float = 0.5) -> Callable[[bytes, list[bytes], random.Random], bytes]:
    """Mutations of a sequence of control frames: of its bytes, or (``p_struct`` of the time) of one message's
    fields (:func:`random_ops` on the unpacked body), re-framed uncompressed with a correct header."""
    from splitrender.protocol.framing import HEADER, MAGIC

    def mut(data: bytes, seeds: list[bytes], rng: random.Random) -> bytes:
        frames = split_frames(data) if rng.random() < p_struct else None
        if not frames:
            return mutate(data, seeds, rng)
        i = rng.randrange(len(frames))
        t, body = frames[i]
        frames[i] = (t, apply_ops(copy.deepcopy(body), random_ops(body, rng)))
        try:
            packed = [(t, msgpack.packb(b, use_bin_type=True, default=_plain)) for t, b in frames]
        except (TypeError, ValueError, OverflowError):
            return mutate(data, seeds, rng)
        return b"".join(HEADER.pack(MAGIC, PROTOCOL_VERSION, t, 0, len(b)) + b for t, b in packed)

    return mut


def _client_core_entry_points(method: str) -> list[EntryPoint]:
    s = method_seeds(method)
    return [
        EntryPoint(f"client.control.{method}", _client_control_seeds(s), _client_control_run(s), (RemoteProtocolError,),
                   mutate=message_mutator()),
        EntryPoint(f"client.datagrams.{method}", _client_datagram_seeds(s), _client_datagram_run(s), (),
                   mutate=datagram_mutator(_fec_ssrcs(s))),
    ]


def _welcome_run(data: bytes) -> Any:
    """A ``Welcome`` and the session data after it, through the client's sans-IO handshake
    (:class:`~splitrender.pipeline.ClientHandshake`, which the live client and the runner drive), then the
    client session core it builds."""
    from splitrender.pipeline import ClientHandshake, ClientOptions

    conn = ClientConnection()
    conn.send(Hello(PROTOCOL_VERSION, "", METHODS, ("h264", "hevc"), 160, 90, 30.0))
    msgs = list(_drain(conn, data, 1 + len(data) % 997))
    if not msgs or not isinstance(msgs[0], Welcome):
        return None   # the client refuses the session (ServerRefusedError), as it should
    hs = ClientHandshake(METHODS)
    for m in msgs:
        if hs.receive_message(m):
            break
    return hs.session(ClientOptions()) if hs.done else None


def _welcome_entry_points() -> list[EntryPoint]:
    seeds = []
    for m in METHODS:
        s = method_seeds(m)
        seeds.append(s.welcome_frame + b"".join(s.session_chunks))
    # a server's Error during the handshake is its refusal (ClientHandshake raises ServerRefusedError, as the live
    # client reports it)
    return [EntryPoint("client.welcome", seeds, _welcome_run, (RemoteProtocolError, ServerRefusedError),
                       mutate=message_mutator())]


# ---------------------------------------------------------------------------- server session core
class ServerCore:
    """A server session core for a captured session, as a driver builds it: its streams' SSRCs those of the
    capture, their retransmission history holding the capture's packets, its frames' send times known."""

    def __init__(self, s: MethodSeeds) -> None:
        self.s = s
        self.core: Any = None
        self.now = 0.0

    def get(self) -> Any:
        if self.core is None:
            self.core = self.new()
        return self.core

    def new(self) -> Any:
        from splitrender.pipeline import ServerOptions, ServerPipeline, ServerSession
        from splitrender.scene.predict import make_predictor

        s = self.s
        tx = ServerPipeline(list(s.specs), 1200, rng=np.random.default_rng(0), fec=True)
        by_name = {d.name: d for d in s.welcome.streams}
        for st in tx.rtp_streams:
            d = by_name.get(st.spec.name)
            if d is not None:
                st.ssrc, st.fec_ssrc = d.ssrc, d.fec_ssrc
        # the live server's default predictor (ServerConfig.predictor)
        core = ServerSession(tx, 30.0, ServerOptions(), 0, 0.0, np.random.default_rng(0), predictor=make_predictor("cv"))
        for name, pkts in s.rtp.items():
            if name in core.streams:
                for d in pkts:
                    core.streams[name].history.store(RtpPacket.parse(d))
        for u in s.updates:
            core.fb.frame_sent(u.frame_id, u.frame_meta.server_time_us)
        core.start(0.0)
        self.now = 0.0
        return core

    def predict(self, msg: Pose) -> None:
        """After a ``Pose`` reached the core (``ServerSession.receive_message``, by the one pose rule of every front
        door), one prediction 50 ms past it, when it was taken."""
        core = self.get()
        t_s = msg.client_time_us / 1e6
        if core.poses.latest_t_s != t_s:
            return
        p = core.predictor.predict(t_s + 0.05)
        if not (np.isfinite(p.position).all() and np.isfinite(p.orientation).all()):
            raise BadPrediction(f"server predictor: {p} from the pose {msg}")


def _server_conn(s: MethodSeeds) -> ServerConnection:
    conn = ServerConnection()
    conn.receive_data(ClientConnection().send(_hello(s.method, s.config.codec)))
    conn.next_event()
    conn.send(Welcome("fuzz", s.method))
    return conn


def _server_control_entry(s: MethodSeeds) -> EntryPoint:
    sc = ServerCore(s)
    template = _server_conn(s)
    stream = next(iter(n.name for n in s.specs))

    def run(data: bytes) -> Any:
        conn = copy.deepcopy(template)
        core = sc.get()
        try:
            for msg in _drain(conn, data, 1 + len(data) % 97):
                sc.now += 5.0
                core.receive_message(msg, sc.now)
                if isinstance(msg, Pose):
                    sc.predict(msg)
                if int(sc.now) % 10 == 0:   # the server's frame loop between messages
                    core.fb.snapshot(core.keyframe_due(sc.now))
        except BaseException:
            sc.core = None   # a protocol error ends the session: the next input gets a new one
            raise

    t0 = 1_700_000_000_000_000
    made = [encode_frame(m) for m in (
        Pose(t0, 1, (0.0, 1.6, 2.5), (0.0, 0.0, 0.0, 1.0)), Pose(t0 + 8333, 2, (0.01, 1.6, 2.49), (0.0, 0.0087, 0.0, 0.99996)),
        KeyframeRequest(stream, "loss"), Stats({"fps": 60.0, "lost": 1}), Bye("done"))]
    fbs = [d for m, d in s.client_frames if isinstance(m, Feedback)]
    seeds = fbs[:12] + made + [b"".join(fbs[:6]), made[0] + made[1] + b"".join(fbs[:2]) + made[2]]
    return EntryPoint("server.control", seeds, run, (RemoteProtocolError,), mutate=message_mutator())


def _server_rtcp_entry(s: MethodSeeds) -> EntryPoint:
    from splitrender.protocol.errors import RtcpError
    from splitrender.protocol.rtcp import compound_feedback, rtcp_route_ssrc

    sc = ServerCore(s)

    def run(data: bytes) -> Any:
        core = sc.get()
        sc.now += 10.0
        try:
            with contextlib.suppress(RtcpError):   # the live server routes RTCP by the media SSRC its headers name
                rtcp_route_ssrc(data)
            core.receive_datagram(data, sc.now)   # then the session parses it: the one RTCP entry of both clocks
            return [d.kind for d in core.datagrams_to_send(sc.now)]   # its answers leave its one way out
        except BaseException:
            sc.core = None
            raise

    me = 0x5EED5EED
    descs = [d for d in s.welcome.streams]
    seqs = {d.name: [RtpPacket.parse(p).sequence_number for p in s.rtp.get(d.name, [])] for d in descs}
    made = []
    for d in descs:
        q = seqs[d.name] or [0]
        made.append(serialize_rtcp(compound_feedback(me, b"fuzz", [
            ReceiverReport(me, (ReportBlock(d.ssrc, 5, 3, 2, 300, 0x12345678, 0x00010000),)),
            GenericNack(me, d.ssrc, tuple(q[1:6])), GenericNack(me, d.ssrc, (q[0], (q[-1] + 1) & 0xFFFF)),
            PictureLossIndication(me, d.ssrc)])))
    seeds = list(s.rtcp_up) + made
    return EntryPoint("server.rtcp", seeds, run, (RemoteProtocolError,))


def _server_nack_entry(s: MethodSeeds) -> EntryPoint:
    """Compound datagrams of generic NACKs (one, a thousand copies of one, every packet of the history, PIDs and
    bitmasks mutated) into the server core as the live server routes them.  Besides the rule, the answer to one
    datagram is at most ``NACK_MAX_PER_DATAGRAM`` packets, none of them twice, and its bytes within the stream's
    rate cap (a share of the media bytes sent plus the floor)."""
    from splitrender.options import NACK_MAX_PER_DATAGRAM, NACK_RATE_FLOOR_BYTES, NACK_RATE_SHARE
    from splitrender.protocol.errors import RtcpError
    from splitrender.protocol.rtcp import rtcp_route_ssrc

    sc = ServerCore(s)
    media = sum(len(d) for pkts in s.rtp.values() for d in pkts)

    def run(data: bytes) -> Any:
        core = sc.get()
        sc.now += 5.0
        try:
            try:
                ssrc = rtcp_route_ssrc(data)
            except RtcpError:
                return None
            if ssrc is None or not core.owns_ssrc(ssrc):
                return None
            core.receive_datagram(data, sc.now)
            resent = [d.data for d in core.datagrams_to_send(sc.now) if d.kind == "resend"]   # no pacer: all leave now
        except BaseException:
            sc.core = None
            raise
        if len(resent) > NACK_MAX_PER_DATAGRAM or len(set(resent)) != len(resent):
            raise UnboundedWork(f"{len(resent)} resends ({len(set(resent))} distinct) for one datagram")
        if sum(map(len, resent)) > NACK_RATE_SHARE * media + NACK_RATE_FLOOR_BYTES * max(1, len(s.rtp)):
            raise UnboundedWork(f"{sum(map(len, resent))} bytes resent against {media} media bytes")
        return len(resent)

    me = 0x5EED5EED
    seeds = []
    for d in s.welcome.streams:
        q = [RtpPacket.parse(p).sequence_number for p in s.rtp.get(d.name, [])] or [0]
        one = GenericNack(me, d.ssrc, tuple(q[:40]))
        rr = ReceiverReport(me, (ReportBlock(d.ssrc, 5, 3, 2, 300, 0, 0),))
        seeds += [serialize_rtcp([rr, one]), serialize_rtcp([rr] + [one] * 1000),
                  serialize_rtcp([rr, GenericNack(me, d.ssrc, tuple(q))]),
                  serialize_rtcp([rr] + [GenericNack(me, d.ssrc, (x,)) for x in q[::-1]])]
    return EntryPoint("server.nack", seeds, run, (RemoteProtocolError,))


def retained_bytes(root: Any, skip: tuple[type, ...] = ()) -> int:
    """Bytes of every object reachable from ``root`` (containers, instance attributes, numpy buffers), each
    counted once; classes, modules, functions and instances of ``skip`` are not followed."""
    seen: set[int] = set()
    stack = [root]
    total = 0
    leaf = (type, types.ModuleType, types.FunctionType, types.BuiltinFunctionType, types.MethodType, str, bytes, int,
            float, bool, type(None))
    while stack:
        o = stack.pop()
        if id(o) in seen:
            continue
        seen.add(id(o))
        if isinstance(o, skip) or isinstance(o, (type, types.ModuleType, types.FunctionType, types.MethodType)):
            continue
        total += sys.getsizeof(o)
        if isinstance(o, leaf):
            continue
        if isinstance(o, dict):
            stack.extend(o.keys())
            stack.extend(o.values())
        elif isinstance(o, (list, tuple, set, frozenset)) or type(o).__name__ == "deque":
            stack.extend(o)
        elif isinstance(o, np.ndarray):
            if o.base is None:
                total += 0  # getsizeof counts an owned buffer
        else:
            d = getattr(o, "__dict__", None)
            if d is not None:
                stack.append(d)
            for name in getattr(type(o), "__slots__", ()):
                if hasattr(o, name):
                    stack.append(getattr(o, name))
    return total


MAX_FLOOD_RSS_MB = 1024.0
"""The flood stops feeding a server whose process grew by this much (a finding, not a crash of this machine)."""


def _feedback_flood_entry(s: MethodSeeds) -> EntryPoint:
    """Valid ``Feedback`` messages (every field in range) naming random streams, some only the session's, into one
    server session core; its retained memory after a quarter of the messages and at the end."""
    from splitrender.pipeline import ServerPipeline

    sc = ServerCore(s)
    template = _server_conn(s)
    names = [sp.name for sp in s.specs]
    st: dict[str, Any] = {"planned": 0, "count": 0, "marks": [], "rss0": 0.0, "stopped": False, "sample": None}

    def start(n: int) -> None:
        sc.core = None
        sc.get()
        st.update(planned=n, count=0, marks=[], rss0=_status_mb("VmRSS") or 0.0, stopped=False, sample=None)

    def make(base: bytes, seeds: list[bytes], rng: random.Random) -> bytes:
        if rng.random() < 0.3:
            pool = names
        else:
            alphabet = "abcdefghijklmnopqrstuvwxyz_0123456789"
            pool = ["".join(rng.choice(alphabet) for _ in range(rng.randint(1, MAX_NAME_LEN))) for _ in range(rng.randint(1, 8))]
        n_lost = rng.randint(0, min(len(pool), MAX_LIST_LEN))
        lost = {n: tuple(sorted(rng.sample(range(1 << 20), rng.randint(1, 32)))) for n in rng.sample(pool, n_lost)}
        applied = {n: rng.randrange(1 << 20) for n in rng.sample(pool, rng.randint(0, min(len(pool), MAX_LIST_LEN)))}
        fid = rng.randrange(1 << 20)
        t = 1_700_000_000_000_000 + fid * 33_333
        fb = Feedback(fid, t, t + 2000, t + 9000, rng.randrange(64), t - 20_000, {"render": 900, "encode": 700}, applied, lost)
        assert all(len(v) <= MAX_LOST_REPORTED for v in lost.values())
        return encode_frame(fb)

    def run(data: bytes) -> Any:
        if st["stopped"]:
            raise UnboundedGrowth(f"the server grew by more than {MAX_FLOOD_RSS_MB:.0f} MB of RSS; flood stopped")
        core = sc.get()
        st["count"] += 1
        try:
            for msg in _drain(copy.deepcopy(template), data, len(data) or 1):
                if st["sample"] is None:
                    st["sample"] = msg
                sc.now += 8.0
                core.receive_message(msg, sc.now)
        finally:
            if st["count"] % 2 == 0:   # the server's frame loop runs about every other Feedback
                core.fb.snapshot(False)
            if st["count"] == max(1, st["planned"] // 4):
                st["marks"].append((st["count"], retained_bytes(core, (ServerPipeline,)), _status_mb("VmRSS") or 0.0))
            if st["count"] % 64 == 0 and (_status_mb("VmRSS") or 0.0) - st["rss0"] > MAX_FLOOD_RSS_MB:
                st["stopped"] = True

    def finish() -> list[Finding]:
        from splitrender.pipeline import ServerPipeline as SP

        core = sc.get()
        st["marks"].append((st["count"], retained_bytes(core, (SP,)), _status_mb("VmRSS") or 0.0))
        (n1, b1, r1), (n2, b2, r2) = st["marks"][0], st["marks"][-1]
        ep.notes.update({"retained_mb": {str(n): round(b / MB, 2) for n, b, _ in st["marks"]},
                         "rss_mb": {str(n): round(r, 1) for n, _, r in st["marks"]}})
        if n2 > n1 and b2 - b1 > 1 * MB and b2 > 1.5 * b1:
            msg = (f"a server session core retained {b2 / MB:.1f} MB after {n2} valid Feedback messages, "
                   f"{b1 / MB:.1f} MB after {n1} (process RSS {r1:.0f} -> {r2:.0f} MB): its state grows with what "
                   f"clients send")
            return [Finding("UnboundedGrowth", msg, 1, f"{n2} Feedback messages like {st['sample']!r} "
                            f"(random stream names in lost/applied, 1-32 lost ids each)", "pipeline.feedback.FeedbackState")]
        return []

    ep = EntryPoint("server.feedback_flood", [b""], run, (RemoteProtocolError,), mutate=make, start=start, finish=finish)
    return ep


def _server_entry_points() -> list[EntryPoint]:
    s = method_seeds("tss")   # reliable data and video streams
    return [_server_control_entry(s), _server_rtcp_entry(s), _server_nack_entry(s), _feedback_flood_entry(method_seeds("video"))]


# ---------------------------------------------------------------------------- transport-cc (issue 46)
class UnboundedWork(HarnessFinding):
    """An input made the code under test hold or return more than its bytes can pay for."""


class RoundTrip(HarnessFinding):
    """A parsed packet did not come back unchanged from its own serialisation."""


def twcc_seeds() -> list[bytes]:
    """Transport-cc feedback as the recorder writes it at sizes from one status to past the MTU, and the issue's
    hollow packets (65,535 declared statuses in 40 bytes), alone and as a 64 KB compound datagram."""
    from splitrender.protocol.twcc import FeedbackRecorder

    rng = random.Random(46)
    out: list[bytes] = []
    for n, loss, spread in ((1, 0.0, 1), (12, 0.1, 3), (90, 0.05, 40), (400, 0.02, 300), (1500, 0.01, 20), (60, 0.5, 1)):
        rec, seq, t = FeedbackRecorder(ssrc=0x5EED), rng.randrange(1 << 16), 1_000_000
        for _ in range(n):
            seq += 1 if rng.random() > loss else rng.randint(2, 40)
            t += rng.randint(0, spread) * 250
            rec.on_packet(seq & 0xFFFF, t)
        out.append(b"".join(bytes(f) for f in rec.feedback()))
    hollow = struct.pack("!IIHHI", 1, 2, 0, 0xFFFF, 0) + struct.pack("!H", 0x1FFF) * 9
    hollow = struct.pack("!BBH", 0x8F, 205, len(hollow) // 4) + hollow
    return out + [hollow, hollow * (64_000 // len(hollow))]


def _twcc_parse_run() -> Callable[[bytes], Any]:
    """``parse_rtcp`` of a datagram, then every transport-cc packet into a sender's history of 2,000 packets:
    what is held is bounded by the bytes (received statuses <= bytes), the history's work by what it holds, and a
    parsed packet serialises back to itself."""
    from splitrender.protocol.twcc import SendHistory, TransportFeedback

    def run(data: bytes) -> Any:
        packets = parse_rtcp(data)
        fbs = [p for p in packets if isinstance(p, TransportFeedback)]
        if sum(len(f.received) for f in fbs) > len(data):
            raise UnboundedWork(f"{sum(len(f.received) for f in fbs)} received statuses from {len(data)} bytes")
        hist = SendHistory()
        for k in range(2000):
            hist.on_sent(k * 500, 1200)
        for f in fbs:
            res = hist.on_feedback(f)
            if len(res) > 2000:
                raise UnboundedWork(f"{len(res)} results from a history of 2000")
            if parse_rtcp(bytes(f)) != [f]:
                raise RoundTrip(f"transport-cc feedback base {f.base_seq} count {f.status_count}")
        return len(fbs)

    return run


def _twcc_recorder_run(data: bytes) -> Any:
    """Arrivals read from the bytes (4 each: a 16-bit transport sequence number and a 16-bit arrival step in
    250 us ticks) into a receiver's recorder, its feedback written and parsed back: the feedback is bounded by the
    arrivals (at most one packet and 64 bytes each, plus one), whatever the sequence numbers skip."""
    from splitrender.protocol.twcc import FeedbackRecorder, TransportFeedback

    rec, t, n = FeedbackRecorder(ssrc=1), 0, len(data) // 4
    for k in range(n):
        seq, step = struct.unpack_from("!HH", data, 4 * k)
        t += step * 250
        rec.on_packet(seq, t)
    fbs = rec.feedback()
    wire = [bytes(f) for f in fbs]
    if len(fbs) > n + 1 or sum(map(len, wire)) > 64 * n + 64:
        raise UnboundedWork(f"{len(fbs)} feedback packets of {sum(map(len, wire))} bytes for {n} arrivals")
    back = [p for w in wire for p in parse_rtcp(w)]
    if back != fbs or not all(isinstance(p, TransportFeedback) for p in back):
        raise RoundTrip("recorder feedback")
    return len(fbs)


def _twcc_entry_points() -> list[EntryPoint]:
    rng = random.Random(4646)
    arrivals = [b"".join(struct.pack("!HH", (k * step) & 0xFFFF, rng.randint(0, 300)) for k in range(n))
                for n, step in ((8, 1), (200, 1), (64, 32_767), (300, 3), (30, 20_000))]
    return [EntryPoint("twcc.parse", twcc_seeds(), _twcc_parse_run(), (RemoteProtocolError,)),
            EntryPoint("twcc.recorder", arrivals, _twcc_recorder_run, ())]


# ---------------------------------------------------------------------------- the browser front door (issue 46)
_OFFER_LOOP: list[Any] = []


def _offer_loop() -> Any:
    """One event loop for the offer entry point (aiortc is asyncio), made once."""
    import asyncio

    if not _OFFER_LOOP:
        _OFFER_LOOP.append(asyncio.new_event_loop())
    return _OFFER_LOOP[0]


def page_offer() -> str:
    """A real offer as the page makes it: recvonly video, and the meta, frame and pose data channels (aiortc
    standing in for the browser)."""
    from aiortc import RTCPeerConnection

    from splitrender.webrtc.app import restrict_ice_host

    restrict_ice_host("127.0.0.1")   # gather on loopback only: network tests here use loopback addresses alone

    async def make() -> str:
        pc = RTCPeerConnection()
        pc.addTransceiver("video", direction="recvonly")
        pc.createDataChannel("meta")
        pc.createDataChannel("frame", ordered=False, maxPacketLifeTime=250)
        pc.createDataChannel("pose", ordered=False, maxRetransmits=0)
        await pc.setLocalDescription(await pc.createOffer())
        sdp = str(pc.localDescription.sdp)
        await pc.close()
        return sdp

    return str(_offer_loop().run_until_complete(make()))


def _webrtc_entry_points() -> list[EntryPoint]:
    """The page's data-channel messages, its session request and recording bodies (as the HTTP handlers decode
    them: bounded JSON, then the parser), and offers through the front door's check and aiortc.  Rule: a result
    or ``PageMessageError`` (a ``RemoteProtocolError``); the HTTP handlers' own rule, every answer below 500, is
    tested live in ``tests/test_webrtc_hostile.py``."""
    from splitrender.webrtc.app import MAX_RECORDING_BODY, MAX_RECORDING_VALUES, MAX_SESSION_BODY, MAX_SESSION_VALUES
    from splitrender.webrtc.messages import ROW_COLUMNS, decode_json, parse_channel_message, parse_recording, parse_session_request
    from splitrender.webrtc.session import try_offer

    offer = page_offer()
    messages = [json.dumps(m).encode() for m in (
        {"type": "pose", "seq": 12, "t_us": 1_733_000_000_000_000, "p": [0.1, 1.6, 2.5], "q": [0.0, 0.0087, 0.0, 0.99996]},
        {"type": "feedback", "frame_id": 40, "displayed_us": 1_733_000_000_100_000, "received_us": 1_733_000_000_080_000},
        {"type": "bye"})]
    request = json.dumps({"type": "offer", "sdp": offer, "method": "atw", "width": 320, "height": 180,
                          "display_hz": 60}).encode()
    row = {k: 1.0 for k in ROW_COLUMNS}
    recording = json.dumps({"rows": [dict(row, frame=float(i)) for i in range(40)], "stats": {"framesDecoded": 38,
                            "decoder": "libvpx"}, "trace": "turn", "duration_s": 5.0, "complete": True,
                            "user_agent": "HeadlessChrome", "record_every": 4}).encode()

    def message(data: bytes) -> Any:
        return parse_channel_message(data.decode("utf-8", "replace"))

    def session_request(data: bytes) -> Any:
        return parse_session_request(decode_json(data, "session request", MAX_SESSION_BODY, MAX_SESSION_VALUES),
                                     ["video", "atw", "sas"], 1920 * 1080)

    def recording_body(data: bytes) -> Any:
        return parse_recording(decode_json(data, "recording", MAX_RECORDING_BODY, MAX_RECORDING_VALUES))

    def offer_run(data: bytes) -> Any:
        return _offer_loop().run_until_complete(try_offer(data.decode("utf-8", "replace")))

    lines = offer.split("\r\n")
    offers = [offer.encode()] + ["\r\n".join(line for line in lines if not line.startswith(drop)).encode()
                                 for drop in ("a=rtpmap:", "a=recvonly", "a=mid:", "a=fingerprint", "m=application")]
    return [EntryPoint("webrtc.message", messages, message, (RemoteProtocolError,)),
            EntryPoint("webrtc.session_request", [request], session_request, (RemoteProtocolError,)),
            EntryPoint("webrtc.recording", [recording], recording_body, (RemoteProtocolError,)),
            EntryPoint("webrtc.offer", offers, offer_run, (RemoteProtocolError,))]


# ---------------------------------------------------------------------------- FEC
def _fec_entry_points() -> list[EntryPoint]:
    from splitrender.protocol.fec import fec_recover, parse_fec

    video, warp = method_seeds("video"), method_seeds("warp")
    eps: list[EntryPoint] = []
    payloads, groups = [], []
    desc = {d.name: d for s in (video, warp) for d in s.welcome.streams}
    for s in (video, warp):
        for name, fecs in s.fec.items():
            media = {RtpPacket.parse(d).sequence_number: d for d in s.rtp.get(name, [])}
            for f in fecs[:8]:
                fp = parse_fec(RtpPacket.parse(f).payload)
                payloads.append(RtpPacket.parse(f).payload)
                prot = [media.get(q) for q in fp.protected()]
                if len(prot) < 2 or any(p is None for p in prot):
                    continue
                for drop in sorted({0, len(prot) - 1}):   # the last is the short one
                    groups.append(_join_lp([f] + [p for i, p in enumerate(prot) if i != drop and p is not None]))
    ssrc = desc["color"].ssrc

    def recover(data: bytes) -> Any:
        chunks = _split_lp(data)
        if not chunks:
            return None
        fec = parse_fec(RtpPacket.parse(chunks[0]).payload)
        media: dict[int, bytes] = {}
        for c in chunks[1:]:
            try:
                media[RtpPacket.parse(c).sequence_number] = c
            except RemoteProtocolError:
                continue
        return fec_recover(fec, ssrc, media.get)

    fec_ssrcs = _fec_ssrcs(video) | _fec_ssrcs(warp)
    eps.append(EntryPoint("fec.parse", payloads, parse_fec, (RemoteProtocolError,)))
    eps.append(EntryPoint("fec.recover", groups, recover, (RemoteProtocolError,), mutate=datagram_mutator(fec_ssrcs, 0.3)))
    for codec, s, name in (("h264", video, "color"), ("hevc", warp, "depth0")):
        d = desc[name]
        seeds = []
        media_ts, fec_ts = _by_timestamp(s.rtp[name]), _by_timestamp(s.fec.get(name, []))
        for i, ts in enumerate(sorted(media_ts)[:12]):
            m, parity = media_ts[ts], fec_ts.get(ts, [])
            drop = len(m) - 1 if i % 2 == 0 else len(m) // 2   # alternately the short last packet, or the middle one
            seeds.append(_join_lp(m[:drop] + m[drop + 1:] + parity if len(m) > 1 else m + parity))
        eps.append(EntryPoint(f"jitter.fec.{codec}", seeds, _jitter_fec_run(codec, d.ssrc, d.fec_ssrc, d.fec_payload_type), (),
                              mutate=datagram_mutator({d.fec_ssrc}, 0.3)))
    return eps


def _jitter_fec_run(codec: str, media_ssrc: int, fec_ssrc: int, fec_pt: int) -> Callable[[bytes], Any]:
    """Media and FEC packets into one jitter buffer, routed as ``ClientPipeline.on_datagram`` routes them."""

    def run(data: bytes) -> Any:
        jb = JitterBuffer(codec, max_packets=256)  # type: ignore[arg-type]
        now = 0.0
        out = []
        for raw in _split_lp(data):
            now += 1.0
            try:
                pkt = RtpPacket.parse(raw)
            except RemoteProtocolError:
                continue
            if pkt.ssrc == fec_ssrc:
                if pkt.payload_type == fec_pt:
                    out += jb.insert_fec(pkt, media_ssrc, now)
            else:
                out += jb.insert(pkt, now)   # malformed payloads are counted, never raised
        out += jb.poll(now + 1000.0)
        jb.missing()
        return out

    return run


def _issue16_entry_points() -> list[EntryPoint]:
    """Seeds and decoders of the entry points of the first campaign (issue 16)."""
    aus = {c: _encode_aus(c) for c in ("h264", "hevc")}
    rtp = {c: _rtp_seeds(c, aus[c]) for c in aus}
    warp_blob, warp_run = _warp_seed()
    sas_frame, sas_session, sas_frame_run, sas_session_run = _sas_seeds()
    meta_blobs = [warp_blob, sas_frame, sas_session, pack_meta({"t_s": 0.0, "pose": [0, 0, 0, 0, 0, 0, 1], "m": {}})]
    raw_meta = [zstandard.ZstdDecompressor().decompress(b) for b in meta_blobs]
    bc4 = bc4_encode(quantize_depth(np.linspace(0.5, 30, W * H).reshape(H, W), 0.1))
    sr = SenderReport(0x1234ABCD, 0xE0000000_00000000, 90000, 10, 5000)
    rtcp = [serialize_rtcp([sr]), serialize_rtcp([ReceiverReport(1, (ReportBlock(0x1234ABCD, 3, 10, 2, 300),)),
                                                  GenericNack(1, 0x1234ABCD, (65534, 65535, 0, 1, 17)),
                                                  PictureLossIndication(1, 0x1234ABCD)])]
    sdp = [make_sdp(c, 5004, 96, parameter_sets=ps).encode() for c, ps in  # type: ignore[arg-type]
           (("h264", [b"\x67\x42\x00\x1e\xab\xcd", b"\x68\xce\x3c\x80"]),
            ("hevc", [b"\x40\x01\x0c\x01", b"\x42\x01\x01\x01", b"\x44\x01\xc1\x72"]))]
    control = _control_seeds()

    def payloads(codec: str) -> list[bytes]:
        per_au: dict[int, list[bytes]] = {}
        for raw in rtp[codec]:
            p = RtpPacket.parse(raw)
            per_au.setdefault(p.timestamp, []).append(p.payload)
        return [_join_lp(v) for v in per_au.values()]

    def sdp_run(data: bytes) -> Any:
        text = data.decode("utf-8", "replace")
        parse_fmtp(text)
        return parameter_sets_from_sdp(text)

    return [
        EntryPoint("unpack_meta.zstd", meta_blobs, lambda d: parse_update_envelope(unpack_meta(d)), (CodecError,)),
        EntryPoint("unpack_meta.msgpack", raw_meta, lambda d: parse_update_envelope(unpack_meta(d)), (CodecError,),
                   encode=_zstd_either),
        EntryPoint("warp.parse_update", [warp_blob], warp_run, (CodecError,)),
        EntryPoint("warp.parse_update.msgpack", [raw_meta[0]], warp_run, (CodecError,), encode=_zstd_either),
        EntryPoint("sas.parse_frame_meta", [sas_frame], sas_frame_run, (CodecError, RemoteProtocolError)),
        EntryPoint("sas.parse_frame_meta.msgpack", [raw_meta[1]], sas_frame_run, (CodecError, RemoteProtocolError),
                   encode=_zstd_either),
        EntryPoint("sas.parse_session.msgpack", [raw_meta[2]], sas_session_run, (CodecError, RemoteProtocolError),
                   encode=_zstd_either),
        EntryPoint("bc4_decode", [bc4], bc4_decode, (CodecError,)),
        EntryPoint("connection.client", control, _connection_run("client"), (RemoteProtocolError,)),
        EntryPoint("connection.server", control, _connection_run("server"), (RemoteProtocolError,)),
        EntryPoint("rtp.parse", rtp["h264"] + rtp["hevc"], RtpPacket.parse, (RemoteProtocolError,)),
        EntryPoint("rtcp.parse", rtcp, parse_rtcp, (RemoteProtocolError,)),
        EntryPoint("h264_depayload", payloads("h264"), lambda d: h264_depayload(_split_lp(d)), (RemoteProtocolError,)),
        EntryPoint("h265_depayload", payloads("hevc"), lambda d: h265_depayload(_split_lp(d)), (RemoteProtocolError,)),
        EntryPoint("jitter.h264", [_join_lp(rtp["h264"])], _jitter_run("h264"), ()),
        EntryPoint("jitter.hevc", [_join_lp(rtp["hevc"])], _jitter_run("hevc"), ()),
        EntryPoint("sdp", sdp, sdp_run, (RemoteProtocolError,)),
        EntryPoint("video.h264", aus["h264"], _video_run("h264"), (CodecError,), slow=True),
        EntryPoint("video.hevc", aus["hevc"], _video_run("hevc"), (CodecError,), slow=True),
    ]


ISSUE16 = ("unpack_meta.zstd", "unpack_meta.msgpack", "warp.parse_update", "warp.parse_update.msgpack",
           "sas.parse_frame_meta", "sas.parse_frame_meta.msgpack", "sas.parse_session.msgpack", "bc4_decode",
           "connection.client", "connection.server", "rtp.parse", "rtcp.parse", "h264_depayload", "h265_depayload",
           "jitter.h264", "jitter.hevc", "sdp", "video.h264", "video.hevc")


def entry_point_groups() -> list[tuple[tuple[str, ...], Callable[[], list[EntryPoint]]]]:
    """(entry point names, builder) of every group; a builder captures only the seeds its group needs."""
    return [
        (ISSUE16, _issue16_entry_points),
        *[((f"session.{m}", f"frame.{m}"), lambda m=m: _client_half_entry_points(m)) for m in METHODS],
        *[((f"client.control.{m}", f"client.datagrams.{m}"), lambda m=m: _client_core_entry_points(m)) for m in METHODS],
        (("client.welcome",), _welcome_entry_points),
        (("server.control", "server.rtcp", "server.nack", "server.feedback_flood"), _server_entry_points),
        (("fec.parse", "fec.recover", "jitter.fec.h264", "jitter.fec.hevc"), _fec_entry_points),
        (("twcc.parse", "twcc.recorder"), _twcc_entry_points),
        (("webrtc.message", "webrtc.session_request", "webrtc.recording", "webrtc.offer"), _webrtc_entry_points),
    ]


def build_entry_points(only: tuple[str, ...] = ()) -> list[EntryPoint]:
    """Seeds and decoders of every untrusted-input entry point (those whose names start with one of ``only``)."""
    def wanted(name: str) -> bool:
        return not only or name.startswith(only)

    out: list[EntryPoint] = []
    for names, build in entry_point_groups():
        if any(wanted(n) for n in names):
            out += [e for e in build() if wanted(e.name)]
    return out


# ---------------------------------------------------------------------------- running
@dataclass
class Report:
    name: str
    inputs: int = 0
    seconds: float = 0.0
    cpu_seconds: float = 0.0
    decoded: int = 0
    unencodable: int = 0
    expected_errors: dict[str, int] = field(default_factory=dict)
    unexpected: dict[str, Finding] = field(default_factory=dict)
    worst_s: float = 0.0
    worst_input: Any = b""
    worst_rerun_s: float = 0.0
    worst_rerun_input: Any = b""
    maxrss_growth_mb: float = 0.0


def _status_mb(key: str) -> float | None:
    """``VmHWM`` (peak RSS) or ``VmRSS`` of this process in MB, from /proc (Linux)."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith(key + ":"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return None


def _reset_peak_rss() -> bool:
    """Reset the peak-RSS mark (``echo 5 > /proc/self/clear_refs``, Linux 4.0+)."""
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        return True
    except OSError:
        return False


def _maxrss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # Linux: kB


def _peak_growth_start() -> tuple[bool, float]:
    """(whether the /proc peak mark was reset, the baseline MB to subtract later)."""
    if _reset_peak_rss() and _status_mb("VmRSS") is not None:
        return True, float(_status_mb("VmRSS"))  # type: ignore[arg-type]
    return False, _maxrss_mb()


def _peak_growth_end(start: tuple[bool, float]) -> float:
    """Peak RSS since :func:`_peak_growth_start` minus the RSS then (MB); without /proc,
    the growth of the process's lifetime peak (which hides growth below an earlier peak)."""
    reset, base = start
    peak = _status_mb("VmHWM") if reset else None
    return (peak if peak is not None else _maxrss_mb()) - base


def _raises(ep: EntryPoint, data: Any) -> str | None:
    try:
        ep.run(data)
    except ep.expected:
        return None
    except Unencodable:
        return None
    except Exception as exc:  # noqa: BLE001 - that is what we look for
        return type(exc).__name__
    return None


def _timed(ep: EntryPoint, data: Any) -> float:
    t0 = time.perf_counter()
    try:
        ep.run(data)
    except Exception:  # noqa: BLE001 - timing only
        pass
    return time.perf_counter() - t0


def minimize(ep: EntryPoint, data: bytes, exc_type: str) -> bytes:
    """Greedy chunk deletion that keeps ``exc_type`` raised (at most :data:`MINIMIZE_TRIES` runs)."""
    tries = 0
    chunk = max(1, len(data) // 2)
    while chunk >= 1 and tries < MINIMIZE_TRIES:
        i, shrunk = 0, False
        while i < len(data) and tries < MINIMIZE_TRIES:
            cand = data[:i] + data[i + chunk:]
            tries += 1
            if _raises(ep, cand) == exc_type:
                data, shrunk = cand, True
            else:
                i += chunk
        if not shrunk:
            chunk //= 2
    return data


def minimize_case(ep: EntryPoint, case: Any, exc_type: str, max_tries: int = 200) -> Any:
    """Greedy: take the first smaller candidate (``ep.shrink``) that still raises ``exc_type``, until none does."""
    assert ep.shrink is not None
    tries = 0
    progress = True
    while progress and tries < max_tries:
        progress = False
        for cand in ep.shrink(case):
            tries += 1
            if _raises(ep, cand) == exc_type:
                case, progress = cand, True
                break
            if tries >= max_tries:
                break
    return case


def _where(exc: BaseException) -> str:
    """Where the failure was raised: the cause's frame for a harness finding (the code under test's)."""
    src = exc.__cause__ if isinstance(exc, HarnessFinding) and exc.__cause__ is not None else exc
    tb = traceback.extract_tb(src.__traceback__)
    if not tb:
        return ""
    return f"{tb[-1].filename}:{tb[-1].lineno}"


def _size(data: Any) -> int:
    return len(data) if isinstance(data, (bytes, bytearray)) else 0


def fuzz(ep: EntryPoint, n: int, seed: int) -> Report:
    rng = random.Random(f"{seed}:{ep.name}")
    rep = Report(ep.name)
    if ep.start is not None:
        ep.start(n)
    rss0 = _peak_growth_start()
    cpu_start = time.process_time()
    t_start = time.perf_counter()
    last_log = t_start
    slowest: list[tuple[float, int, Any]] = []  # min-heap of the SLOWEST_KEPT slowest
    for k in range(n):
        base = rng.choice(ep.seeds)
        data = ep.mutate(base, ep.seeds, rng) if ep.mutate is not None else mutate(base, ep.seeds, rng)
        if ep.encode is not None:
            data = ep.encode(data, rng)
        t0 = time.perf_counter()
        try:
            ep.run(data)
            rep.decoded += 1
        except ep.expected as exc:
            name = type(exc).__name__
            rep.expected_errors[name] = rep.expected_errors.get(name, 0) + 1
        except Unencodable:
            rep.unencodable += 1
        except Exception as exc:  # noqa: BLE001
            name = type(exc).__name__
            f = rep.unexpected.get(name)
            if f is None:
                f = rep.unexpected[name] = Finding(name, str(exc)[:600], 0, data, _where(exc))
            f.count += 1
            if _size(data) < _size(f.smallest):
                f.smallest = data
        dt = time.perf_counter() - t0
        if dt > rep.worst_s:
            rep.worst_s, rep.worst_input = dt, data
        if len(slowest) < SLOWEST_KEPT:
            heapq.heappush(slowest, (dt, k, data))
        elif dt > slowest[0][0]:
            heapq.heapreplace(slowest, (dt, k, data))
        now = time.perf_counter()
        if now - last_log > 30:
            last_log = now
            logger.info("%s: %d/%d inputs, %.0f/s", ep.name, k + 1, n, (k + 1) / (now - t_start))
    rep.inputs = n
    rep.seconds = time.perf_counter() - t_start
    rep.cpu_seconds = time.process_time() - cpu_start
    rep.maxrss_growth_mb = _peak_growth_end(rss0)
    if ep.finish is not None:
        for f in ep.finish():
            rep.unexpected[f.type] = f
    for _, _, data in slowest:
        best = min(_timed(ep, data) for _ in range(3))
        if best >= rep.worst_rerun_s:
            rep.worst_rerun_s, rep.worst_rerun_input = best, data
    for name, f in rep.unexpected.items():
        if isinstance(f.smallest, bytes) and ep.encode is None and ep.start is None:
            f.smallest = minimize(ep, f.smallest, name)   # a reproducer of the raw input (encoded inputs as fed)
        elif ep.shrink is not None and not isinstance(f.smallest, (bytes, str)):
            f.smallest = minimize_case(ep, f.smallest, name)
    return rep


def show_input(ep: EntryPoint, data: Any) -> dict[str, Any]:
    """An input for the report: hex for bytes, the entry point's text for a structured one."""
    if isinstance(data, (bytes, bytearray)):
        return {"hex": bytes(data).hex()[:HEX_MAX], "len": len(data)}
    text = data if isinstance(data, str) else (ep.show(data) if ep.show is not None else repr(data))
    return {"repr": text[:REPR_MAX]}


def _as_json(rep: Report, ep: EntryPoint | None = None) -> dict[str, Any]:
    ep = ep or EntryPoint(rep.name, [], lambda d: None, ())

    def inp(data: Any, prefix: str) -> dict[str, Any]:
        return {f"{prefix}_{k}": v for k, v in show_input(ep, data).items()}

    return {
        "inputs": rep.inputs, "seconds": round(rep.seconds, 2), "cpu_seconds": round(rep.cpu_seconds, 2),
        "inputs_per_s": round(rep.inputs / rep.seconds, 1) if rep.seconds else None,
        "inputs_per_cpu_s": round(rep.inputs / rep.cpu_seconds, 1) if rep.cpu_seconds else None,
        "slow": ep.slow,
        "decoded": rep.decoded, "unencodable": rep.unencodable, "expected_errors": dict(sorted(rep.expected_errors.items())),
        "unexpected": {k: {"count": f.count, "message": f.message, "raised_at": f.where, **inp(f.smallest, "reproducer")}
                       for k, f in rep.unexpected.items()},
        "worst_ms": round(rep.worst_s * 1000, 3), "worst_input_len": _size(rep.worst_input),
        "worst_ms_retimed": round(rep.worst_rerun_s * 1000, 3),
        "worst_retimed_input_len": _size(rep.worst_rerun_input), **inp(rep.worst_rerun_input, "worst_retimed_input"),
        "peak_rss_growth_mb": round(rep.maxrss_growth_mb, 1),
        **({"notes": ep.notes} if ep.notes else {}),
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--inputs", type=int, default=100_000, help="inputs per fast entry point")
    ap.add_argument("--slow-inputs", type=int, default=2_000,
                    help="inputs per slow entry point (the video decoders, frame.*, session.probes)")
    ap.add_argument("--only", default="", help="comma-separated entry point names (prefixes)")
    ap.add_argument("--list", action="store_true", help="list the entry point names and exit")
    ap.add_argument("--seed", type=int, default=16)
    ap.add_argument("--out", type=Path, default=RESULTS)
    args = ap.parse_args(argv)
    if args.list:
        for names, _ in entry_point_groups():
            print("\n".join(names))
        return 0
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    logging.getLogger("splitrender").setLevel(logging.CRITICAL)  # the decoders log every bad input
    only = tuple(x for x in args.only.split(",") if x)
    eps = build_entry_points(only)
    results: dict[str, Any] = {}
    for ep in eps:
        n = args.slow_inputs if ep.slow else args.inputs
        rep = fuzz(ep, n, args.seed)
        results[ep.name] = _as_json(rep, ep)
        r = results[ep.name]
        logger.info("%-30s %7d inputs %7.0f/s (%7.0f per CPU s)  worst %8.2f ms (re-timed %.2f ms)  peak RSS +%.1f MB  unexpected %s",
                    ep.name, n, r["inputs_per_s"] or 0, r["inputs_per_cpu_s"] or 0, r["worst_ms"], r["worst_ms_retimed"], r["peak_rss_growth_mb"],
                    {k: v["count"] for k, v in r["unexpected"].items()} or "none")
    out = {
        "machine": {"python": platform.python_version(), "platform": platform.platform(),
                    "zstandard": zstandard.__version__, "msgpack": ".".join(map(str, msgpack.version))},
        "args": {"inputs": args.inputs, "slow_inputs": args.slow_inputs, "seed": args.seed},
        "peak_rss_mb": round(_maxrss_mb(), 1),
        "unexpected_total": sum(len(r["unexpected"]) for r in results.values()),
        "entry_points": results,
    }
    if not only:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(out, indent=2) + "\n")
        logger.info("wrote %s", args.out)
    else:
        print(json.dumps(out, indent=2))
    return 1 if out["unexpected_total"] else 0


if __name__ == "__main__":
    raise SystemExit(main())
