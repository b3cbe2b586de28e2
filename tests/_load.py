"""The machine's load, measured beside the few tests whose requirement is a wall-clock time.

The suite must pass with two busy loops beside it.  A bound such as "the server exits within 2 s of SIGTERM" is
a requirement of an otherwise idle machine; on a loaded one every process gets a share of a core, and the same
work takes longer in proportion.  :class:`LoadMeter` measures that proportion over the window the test times,
as a baseline from the same run: a thread does fixed pure-Python work and compares the wall time it took with
the CPU time it got.  It reads 1.0 where the thread has a core to itself (never less) and read 3.8 on this
2-core machine at load 24.  A timed bound is then ``requirement x slowdown``: a shutdown that waits on a timeout
or on the stream's end still fails it, since waiting costs wall time without competing for a core.
"""

from __future__ import annotations

import threading
import time

CHUNK_CPU_S = 0.02
"""CPU seconds of work per sample."""


def _spin(cpu_s: float) -> tuple[float, float]:
    """Do ``cpu_s`` of this thread's CPU time in pure Python; (wall seconds, CPU seconds) it took."""
    t0, c0 = time.perf_counter(), time.thread_time()
    n = 0
    while time.thread_time() - c0 < cpu_s:
        for _ in range(2000):
            n += 1
    return time.perf_counter() - t0, time.thread_time() - c0


class LoadMeter:
    """``with LoadMeter() as m: ...`` then ``m.slowdown``: wall over CPU time of fixed work done beside the block,
    at least 1."""

    def __init__(self) -> None:
        self._stop = threading.Event()
        self._wall = 0.0
        self._cpu = 0.0
        self._thread = threading.Thread(target=self._run, name="load-meter", daemon=True)

    def _run(self) -> None:
        while True:
            wall, cpu = _spin(CHUNK_CPU_S)
            self._wall += wall
            self._cpu += cpu
            if self._stop.is_set():   # at least one sample, taken while the block ran
                return

    def __enter__(self) -> LoadMeter:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()

    @property
    def slowdown(self) -> float:
        return max(1.0, self._wall / self._cpu) if self._cpu > 0 else 1.0


def slowdown_over(seconds: float) -> float:
    """The slowdown measured over ``seconds`` of wall time with nothing else running in this process: for a test
    whose timed work runs in this process, where a spinning thread beside it would take the interpreter lock from
    the work it measures.  Take it just before and just after that work."""
    with LoadMeter() as m:
        time.sleep(seconds)
    return m.slowdown
