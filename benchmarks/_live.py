"""What the live benchmarks share: a ``splitrender serve`` in its own process on loopback (as deployed: in one
process with the client and the relay, the three compete for one interpreter lock and delay each other's datagrams
by 100s of ms)."""

from __future__ import annotations

import asyncio
import contextlib
import socket
import subprocess
import sys
from collections.abc import AsyncIterator, Sequence

LOOPBACK = "127.0.0.1"


def free_port() -> int:
    with socket.socket() as sk:
        sk.bind((LOOPBACK, 0))
        return int(sk.getsockname()[1])


@contextlib.asynccontextmanager
async def served(args: Sequence[str]) -> AsyncIterator[tuple[int, int]]:
    """``splitrender serve`` on loopback with ``args`` beside the address options, started and serving: yields its
    (TCP port, UDP port); terminated on the way out."""
    port, udp_port = free_port(), free_port()
    srv = subprocess.Popen([sys.executable, "-m", "splitrender.cli", "serve", "--host", LOOPBACK, "--port", str(port),
                            "--udp-port", str(udp_port), *args], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        assert srv.stderr is not None
        line = await asyncio.get_running_loop().run_in_executor(None, srv.stderr.readline)
        if "serving on" not in line:
            raise RuntimeError(f"server did not start: {line}")
        yield port, udp_port
    finally:
        srv.terminate()
        srv.communicate(timeout=15)
