"""Render workers: the live server's GL and codec work in child processes, with a watchdog.

moderngl holds the interpreter lock during GL calls, so a render stuck inside Mesa
(seen on llvmpipe: a ``Framebuffer.read`` spinning forever) froze every session, the
control sockets and the signal handlers of a server that rendered on a thread.  Here
the event loop's process never touches GL or a codec:

* a :class:`RenderWorker` is a child process that loads the scene, creates its own
  :class:`~splitrender.render.Renderer` (EGL), the scene producers, and each session's method half and video
  encoders (its :class:`~splitrender.pipeline.FrameMaker`);
* the server talks to it over a socket pair with :mod:`multiprocessing`'s framing
  (4-byte big-endian length, pickled tuple), from asyncio, without threads (:mod:`splitrender.pipeline.processes`);
* every request has a deadline (the **watchdog**): a worker that misses it is killed
  with SIGKILL, every session it served ends with an error naming the request and the
  deadline, and the next session gets a fresh worker; the event loop stays free, so the
  other sessions keep streaming and SIGTERM still stops the server.

Isolation (``ServerConfig.isolation``): ``"session"`` (the default) gives each session
its own worker, so a hung render ends that session only, at the cost of one renderer
and one set of scene producers per session; ``"server"`` runs every session in one
worker that shares the producers' per-frame work (as virtual time does) and whose
watchdog ends every session at once.  A warm spare worker (scene loaded, renderer
created, shaders compiled) waits for the next session so that a session starts without
paying for the process start.

Workers fork from a :mod:`multiprocessing` fork server that imported the heavy modules
(numpy, moderngl, PyAV, the methods) once and never created a GL context
(:func:`~splitrender.pipeline.processes.worker_context`).
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import logging
import os
import pickle
import signal
import socket
import time
import traceback
from typing import Any

from splitrender.errors import WorkerDied, WorkerError, WorkerTimeout, describe_error  # noqa: F401 - re-exported
from splitrender.pipeline.frames import SessionFrames
from splitrender.pipeline.processes import WORKER_ENV, frame_bytes, read_frame, worker_context

__all__ = ["RenderWorker", "WorkerError", "WorkerTimeout", "WorkerDied", "worker_context", "WORKER_ENV"]

logger = logging.getLogger(__name__)


# ---------------------------------------------------------------------- the event-loop side

class RenderWorker:
    """One worker process and the asyncio end of its socket.

    ``await call(op, *args, deadline_s=...)`` sends one request and waits for its answer;
    requests are answered in order (a session's frames: :meth:`~splitrender.pipeline.live.LiveSession._make_frame`).  Raises :class:`WorkerError` (the worker reported an
    exception; it keeps running), :class:`WorkerTimeout` (deadline missed; the worker is
    killed) or :class:`WorkerDied`.
    """

    _ids = itertools.count(1)

    def __init__(self, scene: str, server_fps: int, gi_hz: float = 0.0) -> None:
        self.scene = scene
        self.server_fps = server_fps
        self.gi_hz = gi_hz
        self.name = f"sr-render-{next(self._ids)}"
        self.process: Any = None
        self.dead: str | None = None
        """Why the worker is unusable (killed, crashed, closed), or ``None``."""
        self._reader: asyncio.StreamReader | None = None
        self._writer: asyncio.StreamWriter | None = None
        self._lock = asyncio.Lock()

    @property
    def pid(self) -> int | None:
        return None if self.process is None else self.process.pid

    async def start(self, deadline_s: float) -> None:
        """Start the process and wait until it has its scene, renderer and compiled shaders."""
        ctx = worker_context()
        parent, child = ctx.Pipe(duplex=True)
        self.process = ctx.Process(target=_worker_main, args=(child, self.scene, self.server_fps, self.gi_hz), name=self.name,
                                   daemon=True)
        # a few milliseconds from the fork server (its own start, once per server process, takes longer);
        # synchronous, so a cancelled start never leaves a process behind
        self.process.start()
        child.close()
        sock = socket.socket(fileno=os.dup(parent.fileno()))
        parent.close()
        try:
            self._reader, self._writer = await asyncio.open_connection(sock=sock, limit=1 << 20)
            await self.call("ping", deadline_s=deadline_s)
        except BaseException:
            sock.close()
            await self.close()
            raise
        logger.debug("%s: ready (pid %d)", self.name, self.pid)

    async def call(self, op: str, *args: Any, deadline_s: float) -> Any:
        if self.dead is not None:
            raise WorkerDied(f"render worker {self.name}: {self.dead}")
        assert self._reader is not None and self._writer is not None, "start() first"
        blob = pickle.dumps((op, args), protocol=pickle.HIGHEST_PROTOCOL)
        # the exchange runs to its end even when the caller is cancelled (a session ending mid-frame), so the
        # next request's answer is never read in its place and a shared worker is not lost with one session
        task = asyncio.ensure_future(self._exchange(op, blob, deadline_s))
        task.add_done_callback(lambda t: t.cancelled() or t.exception())
        status, value = await asyncio.shield(task)
        if status == "ok":
            return value
        raise WorkerError(value)

    async def _exchange(self, op: str, blob: bytes, deadline_s: float) -> Any:
        assert self._reader is not None and self._writer is not None
        async with self._lock:
            if self.dead is not None:
                raise WorkerDied(f"render worker {self.name}: {self.dead}")
            try:
                self._writer.write(frame_bytes(blob))
                return await asyncio.wait_for(read_frame(self._reader), deadline_s)
            except asyncio.TimeoutError:
                why = f"{op} missed its {deadline_s:g} s deadline"
                self.kill(why)
                raise WorkerTimeout(f"render worker {self.name}: {why}; the worker was killed") from None
            except (ConnectionError, asyncio.IncompleteReadError, OSError) as exc:
                code = self.process.exitcode if self.process is not None else None
                self.kill(f"connection lost during {op}: {exc or type(exc).__name__}")
                raise WorkerDied(f"render worker {self.name}: ended during {op} (exit code {code})") from None

    def kill(self, why: str) -> None:
        """SIGKILL the process now (idempotent); every later call raises :class:`WorkerDied`."""
        if self.dead is None:
            self.dead = why
            logger.warning("render worker %s (pid %s): %s", self.name, self.pid, why)
        self._end_now()

    def _end_now(self) -> None:
        """SIGKILL the process if it still runs and close the socket."""
        if self.process is not None and self.process.is_alive():
            with contextlib.suppress(OSError, AttributeError):
                self.process.kill()
        if self._writer is not None:
            self._writer.close()

    async def close(self, grace_s: float = 0.5) -> None:
        """Ask an idle worker to stop (a busy one is killed at once), kill it after ``grace_s``, reap it.
        Cancelling this still kills the process and closes the socket."""
        p = self.process
        try:
            if self.dead is None and self._writer is not None and not self._lock.locked():
                self.dead = "closed"
                with contextlib.suppress(Exception):
                    self._writer.write(frame_bytes(pickle.dumps(("stop", ()))))
                    await asyncio.wait_for(self._writer.drain(), grace_s)
                end = time.monotonic() + grace_s
                while p is not None and p.is_alive() and time.monotonic() < end:
                    await asyncio.sleep(0.02)
        finally:
            self.dead = self.dead or "closed"
            self._end_now()
        if p is not None:
            for _ in range(100):
                if not p.is_alive():
                    break
                await asyncio.sleep(0.01)
            with contextlib.suppress(Exception):
                p.join(0)


# ---------------------------------------------------------------------- the worker process

class _Worker(SessionFrames):
    """The worker process's sessions (:class:`~splitrender.pipeline.frames.SessionFrames`: the scene, renderer,
    producers and each session's frame maker) and, per session, the frame the test hook hangs on."""

    def __init__(self, scene_name: str, server_fps: int, gi_hz: float = 0.0) -> None:
        super().__init__(scene_name, server_fps, gi_hz)
        self.hang_at: dict[str, int] = {}

    def ping(self) -> int:
        return os.getpid()

    def open(self, sid: str, opening: Any, hang_frame: int = -1) -> Any:
        self.hang_at[sid] = hang_frame
        return super().open(sid, opening)

    def frame(self, sid: str, order: Any) -> Any:
        if order.frame_id == self.hang_at.get(sid, -1):
            _hang()
        return super().frame(sid, order)


def _hang() -> None:
    """The test hook's hang: spin holding this process's interpreter lock, as the Mesa stall did."""
    while True:
        pass


def _worker_main(conn: Any, scene_name: str, server_fps: int, gi_hz: float = 0.0) -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)      # Ctrl-C reaches the whole group; the server stops us
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    try:
        worker: _Worker | None = _Worker(scene_name, server_fps, gi_hz)
        setup_error = None
    except Exception as exc:  # noqa: BLE001 - reported on the first request
        worker, setup_error = None, f"worker start failed: {describe_error(exc)}"
    while True:
        try:
            op, args = conn.recv()
        except (EOFError, OSError):
            return
        if op == "stop":
            return
        try:
            if worker is None:
                raise RuntimeError(setup_error)
            fn = getattr(worker, op)
            reply = ("ok", fn(*args))
        except Exception as exc:  # noqa: BLE001 - one session's failure is answered, the worker goes on
            traceback.print_exc()           # to the server's stderr, for whoever debugs the method
            reply = ("error", describe_error(exc))
        try:
            conn.send(reply)
        except (OSError, ValueError):
            return

