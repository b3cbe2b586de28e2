"""The process plumbing of the live server's render workers (:mod:`splitrender.server.worker`, which holds their
watchdog and their sessions' :class:`~.frames.SessionFrames`): the :mod:`multiprocessing` context they start from and
the framing of the socket pair they talk over.

Workers fork from a :mod:`multiprocessing` fork server that imported the heavy modules (numpy, moderngl, PyAV, the
methods) once and never created a GL context.  The server talks to a worker over a socket pair with
:mod:`multiprocessing`'s framing (4-byte big-endian length, pickled tuple), from asyncio, without threads; the worker
answers with its ``Connection``'s ``recv`` and ``send``.
"""

from __future__ import annotations

import asyncio
import multiprocessing
import os
import pickle
import struct
from multiprocessing import forkserver
from typing import Any

__all__ = ["WORKER_ENV", "worker_context", "frame_bytes", "read_frame"]

_PRELOAD = ["splitrender.server.worker", "splitrender.render", "splitrender.methods", "splitrender.pipeline",
            "splitrender.scene.loader", "splitrender.codecs.video"]

WORKER_ENV = {"OPENBLAS_NUM_THREADS": "1"}
"""Environment the render workers start with, where the server's own environment does not set it.  One BLAS thread:
their matrices are small (the probes' ray weights, the methods' per-patch math), and llvmpipe's threads fill the
cores; a second BLAS thread waiting for a core made the probes' 256 x 384 x 256 visibility product take 52 ms
where one thread takes 1.7 (2 cores, load ~18).  The same bits either way (the probes hashed alike)."""

_ctx: Any = None


def worker_context() -> Any:
    """The multiprocessing context workers start from: a fork server with the heavy modules preloaded (safe: the fork
    server is single-threaded and never creates a GL context), started here with :data:`WORKER_ENV` unless it runs
    already (this process's own environment is left as it was)."""
    global _ctx
    if _ctx is None:
        if "forkserver" not in multiprocessing.get_all_start_methods():  # pragma: no cover - non-Unix
            _ctx = multiprocessing.get_context("spawn")
            return _ctx
        _ctx = multiprocessing.get_context("forkserver")
        _ctx.set_forkserver_preload(_PRELOAD)
    if _ctx.get_start_method() == "forkserver":
        saved = {k: os.environ.get(k) for k in WORKER_ENV}
        for k, v in WORKER_ENV.items():
            os.environ.setdefault(k, v)
        try:
            forkserver.ensure_running()
        finally:
            for k, old in saved.items():
                if old is None:
                    os.environ.pop(k, None)
                else:
                    os.environ[k] = old
    return _ctx


def frame_bytes(blob: bytes) -> bytes:
    """``blob`` framed as a ``multiprocessing.Connection`` frames it (the length; over 2 GiB, -1 then 8 bytes)."""
    n = len(blob)
    head = struct.pack("!i", n) if n <= 0x7FFFFFFF else struct.pack("!i", -1) + struct.pack("!Q", n)
    return head + blob


async def read_frame(reader: asyncio.StreamReader) -> Any:
    """The next frame from ``reader`` (as :func:`frame_bytes` frames it), unpickled."""
    head = await reader.readexactly(4)
    (n,) = struct.unpack("!i", head)
    if n == -1:
        (n,) = struct.unpack("!Q", await reader.readexactly(8))
    return pickle.loads(await reader.readexactly(n))
