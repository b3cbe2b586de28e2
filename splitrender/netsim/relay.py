"""An asyncio shaping relay for UDP and TCP that applies a :class:`PathSpec` live.

Client -> server traffic goes through the path's ``uplink`` :class:`Link`, server ->
client traffic through its ``downlink``.  One Link per direction is shared by every
UDP mapping and TCP connection of the relay, like one bottleneck per direction of a
real path.  Link time is the event loop's clock (``loop.time()``, s) less the relay's
origin, the moment its first listener started (:attr:`Relay.origin_wall_s` gives it on
the wall clock): a time-windowed impairment (a delay spike) and a mahimahi trace begin
there, as they begin at 0 in virtual time, instead of at an arbitrary phase of the
loop's clock.

UDP: the relay listens on ``listen``, learns the client's address from the first
datagram (datagrams from other addresses are dropped and counted), and forwards each
datagram through the Link (drop / delay / duplicate / corrupt) to ``target`` from an
ephemeral socket; replies come back through the downlink.  The model sees each
datagram as payload + :data:`UDP_OVERHEAD_BYTES` (IPv4 + UDP headers).

TCP: each accepted connection gets its own connection to ``target``; bytes are cut
into :data:`TCP_SEGMENT_BYTES` segments and sent through the Link with
``reliable=True``: only delay, jitter and rate apply, order is always kept, and a
segment the model would lose is instead delayed by one retransmission timeout
(:data:`~splitrender.netsim.models.DEFAULT_RTO_S`, 200 ms), holding back the bytes
behind it, which is what a loss costs a TCP stream.  Queues are bounded, so a slow
shaped path pushes back on the sender through TCP flow control.
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import heapq
import ipaddress
import itertools
import logging
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from splitrender.errors import NetworkConfigError
from splitrender.netsim.models import Delivery, Link, PathSpec, corrupt

logger = logging.getLogger(__name__)

Address = tuple[str, int]

#: IPv4 + UDP header bytes added to each datagram's size for the rate model.
UDP_OVERHEAD_BYTES = 28
#: Payload bytes per modelled TCP segment (an Ethernet MSS).
TCP_SEGMENT_BYTES = 1448
#: IPv4 + TCP header bytes added to each segment for the rate model.
TCP_OVERHEAD_BYTES = 52
#: Most datagrams waiting in one UDP delay line before new ones are dropped.
UDP_MAX_IN_FLIGHT = 65536
#: Most segments buffered per TCP connection and direction.
TCP_MAX_QUEUED_SEGMENTS = 256
_TCP_READ_BYTES = 65536


@dataclass(frozen=True)
class DirectionStats:
    """Counters for one direction (packets are datagrams or TCP segments; bytes payload)."""

    packets_in: int = 0
    packets_out: int = 0
    packets_dropped: int = 0
    """Lost to the impairment: the link model's loss, or its queue full (what netem would drop)."""
    packets_undeliverable: int = 0
    """Not lost to the impairment: the relay's own delay line was full, or the send failed (the peer's port
    closed, e.g. a client that has left while the server still sends)."""
    packets_duplicated: int = 0
    packets_corrupted: int = 0
    bytes_in: int = 0
    bytes_out: int = 0


@dataclass(frozen=True)
class RelayStats:
    """A snapshot of the relay's counters."""

    uplink: DirectionStats
    downlink: DirectionStats
    udp_foreign_dropped: int = 0
    tcp_connections_total: int = 0
    tcp_connections_open: int = 0


class _Counters:
    __slots__ = tuple(f.name for f in dataclasses.fields(DirectionStats))

    def __init__(self) -> None:
        for name in self.__slots__:
            setattr(self, name, 0)

    def snapshot(self) -> DirectionStats:
        return DirectionStats(**{name: getattr(self, name) for name in self.__slots__})


def is_loopback_host(host: str) -> bool:
    """True for ``localhost`` and loopback literals (127.0.0.0/8, ::1)."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


class _DelayLine:
    """Datagrams waiting for their delivery time; one timer armed for the earliest."""

    def __init__(
        self,
        loop: asyncio.AbstractEventLoop,
        send: Callable[[bytes, Address | None], None],
        counters: _Counters,
        max_packets: int = UDP_MAX_IN_FLIGHT,
    ) -> None:
        self._loop = loop
        self._send = send
        self._counters = counters
        self._max = max_packets
        self._heap: list[tuple[float, int, bytes, Address | None]] = []
        self._seq = itertools.count()
        self._timer: asyncio.TimerHandle | None = None
        self._closed = False

    def push(self, when_s: float, data: bytes, addr: Address | None) -> None:
        if self._closed:
            return
        if not self._heap and when_s <= self._loop.time():
            self._deliver(data, addr)
            return
        if len(self._heap) >= self._max:
            self._counters.packets_undeliverable += 1
            return
        heapq.heappush(self._heap, (when_s, next(self._seq), data, addr))
        if self._heap[0][0] == when_s:
            self._arm()

    def _arm(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
        self._timer = self._loop.call_at(self._heap[0][0], self._fire) if self._heap else None

    def _fire(self) -> None:
        self._timer = None
        now = self._loop.time()
        heap = self._heap
        while heap and heap[0][0] <= now:
            _, _, data, addr = heapq.heappop(heap)
            self._deliver(data, addr)
        self._arm()

    def _deliver(self, data: bytes, addr: Address | None) -> None:
        try:
            self._send(data, addr)
        except OSError as exc:  # e.g. the transport is closing
            logger.debug("relay: send failed: %s", exc)
            self._counters.packets_undeliverable += 1
            return
        self._counters.packets_out += 1
        self._counters.bytes_out += len(data)

    def close(self) -> None:
        self._closed = True
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        self._heap.clear()


class _Protocol(asyncio.DatagramProtocol):
    def __init__(self, on_datagram: Callable[[bytes, Address], None], name: str) -> None:
        self._on_datagram = on_datagram
        self._name = name

    def datagram_received(self, data: bytes, addr: Address) -> None:  # type: ignore[override]
        self._on_datagram(data, addr)

    def error_received(self, exc: Exception) -> None:
        logger.debug("relay %s: %s", self._name, exc)


class Relay:
    """Shapes UDP and TCP between a client and a server on loopback (see module docs).

    ``seed`` makes the impairment decisions repeatable for the same arrival times.
    Non-loopback addresses are refused unless ``allow_remote`` is true.
    """

    def __init__(self, path: PathSpec, seed: int = 0, *, allow_remote: bool = False) -> None:
        self.path = path
        self.seed = seed
        self.allow_remote = allow_remote
        self._uplink = Link(path.uplink, np.random.default_rng([seed, 0]))
        self._downlink = Link(path.downlink, np.random.default_rng([seed, 1]))
        self._corrupt_rng = np.random.default_rng([seed, 2])
        self._up = _Counters()
        self._down = _Counters()
        self._udp_foreign = 0
        self._tcp_total = 0
        self._tcp_open = 0
        self._transports: list[asyncio.BaseTransport] = []
        self._delay_lines: list[_DelayLine] = []
        self._servers: list[asyncio.Server] = []
        self._tcp_tasks: set[asyncio.Task[None]] = set()
        self._closed = False
        self._origin: float | None = None
        self.origin_wall_s: float | None = None
        """Wall-clock time (``time.time()``) of link time 0: when the first listener started."""

    # -- helpers ------------------------------------------------------------------

    def _start_clock(self) -> None:
        if self._origin is None:
            self._origin = asyncio.get_running_loop().time()
            self.origin_wall_s = time.time()

    def _send(self, link: Link, now_loop_s: float, size: int, reliable: bool = False) -> list[Delivery]:
        """``link.send`` on link time (the loop's clock less the origin), deliveries back on the loop's clock."""
        origin = self._origin or 0.0
        return [dataclasses.replace(d, time_s=d.time_s + origin)
                for d in link.send(now_loop_s - origin, size, reliable=reliable)]

    def _check_address(self, role: str, addr: Address) -> None:
        host, port = addr
        if not isinstance(port, int) or not 0 <= port <= 65535:
            raise NetworkConfigError(f"relay: {role} port must be 0..65535, got {port!r}")
        if not self.allow_remote and not is_loopback_host(host):
            raise NetworkConfigError(
                f"relay: {role} address {host!r} is not loopback (pass allow_remote to permit it)"
            )

    def stats(self) -> RelayStats:
        """Counters so far, per direction."""
        return RelayStats(
            uplink=self._up.snapshot(),
            downlink=self._down.snapshot(),
            udp_foreign_dropped=self._udp_foreign,
            tcp_connections_total=self._tcp_total,
            tcp_connections_open=self._tcp_open,
        )

    # -- UDP ----------------------------------------------------------------------

    async def start_udp(self, listen: Address, target: Address) -> Address:
        """Relay UDP from ``listen`` to ``target``; returns the bound listen address."""
        self._check_address("target", target)
        bound, _, _ = await self._start_udp(listen, target)
        return bound

    async def start_udp_unbound(self, listen: Address) -> tuple[Address, Address, Callable[[Address], None]]:
        """Relay UDP from ``listen`` to a target named later (a WebRTC peer whose port is known only once its
        answer is made).  Returns the bound listen address, the address of the socket the target will see the
        client's datagrams come from, and ``set_target(address)``; until it is called, datagrams towards the
        target are counted undeliverable."""
        return await self._start_udp(listen, None)

    async def _start_udp(self, listen: Address, target: Address | None) -> tuple[Address, Address, Callable[[Address], None]]:
        self._check_address("listen", listen)
        self._start_clock()
        loop = asyncio.get_running_loop()
        client_addr: list[Address] = []
        target_addr: list[Address] = [target] if target is not None else []

        def set_target(addr: Address) -> None:
            self._check_address("target", addr)
            target_addr[:] = [addr]
            logger.info("relay udp %s: target is %s", listen, addr)

        def to_server(data: bytes, _addr: Address | None) -> None:
            if not target_addr:
                raise OSError("no target yet")      # counted undeliverable by the delay line
            if target is not None:
                server_t.sendto(data)
            else:
                server_t.sendto(data, target_addr[0])

        def to_client(data: bytes, addr: Address | None) -> None:
            listen_t.sendto(data, addr)

        up_line = _DelayLine(loop, to_server, self._up)
        down_line = _DelayLine(loop, to_client, self._down)

        def shape(data: bytes, link: Link, counters: _Counters, line: _DelayLine,
                  addr: Address | None) -> None:
            counters.packets_in += 1
            counters.bytes_in += len(data)
            deliveries = self._send(link, loop.time(), len(data) + UDP_OVERHEAD_BYTES)
            if not deliveries:
                counters.packets_dropped += 1
                return
            if len(deliveries) > 1:
                counters.packets_duplicated += 1
            for d in deliveries:
                payload = data
                if d.corrupted:
                    counters.packets_corrupted += 1
                    payload = corrupt(data, self._corrupt_rng)
                line.push(d.time_s, payload, addr)

        def from_client(data: bytes, addr: Address) -> None:
            if not client_addr:
                client_addr.append(addr)
                logger.info("relay udp %s: client is %s", listen, addr)
            elif addr != client_addr[0]:
                self._udp_foreign += 1
                return
            shape(data, self._uplink, self._up, up_line, None)

        def from_server(data: bytes, addr: Address) -> None:
            if target is None and (not target_addr or tuple(addr[:2]) != target_addr[0]):
                self._udp_foreign += 1
                return
            if client_addr:
                shape(data, self._downlink, self._down, down_line, client_addr[0])

        listen_t, _ = await loop.create_datagram_endpoint(
            lambda: _Protocol(from_client, f"udp {listen} client side"), local_addr=listen
        )
        try:
            if target is not None:
                server_t, _ = await loop.create_datagram_endpoint(
                    lambda: _Protocol(from_server, f"udp {target} server side"), remote_addr=target
                )
            else:
                server_t, _ = await loop.create_datagram_endpoint(
                    lambda: _Protocol(from_server, f"udp {listen} server side"), local_addr=(listen[0], 0)
                )
        except BaseException:
            listen_t.close()
            raise
        self._transports += [listen_t, server_t]
        self._delay_lines += [up_line, down_line]
        bound = listen_t.get_extra_info("sockname")
        inner = server_t.get_extra_info("sockname")
        logger.info("relay udp %s -> %s started", bound[:2], target if target is not None else "(target to come)")
        return (bound[0], bound[1]), (inner[0], inner[1]), set_target

    # -- TCP ----------------------------------------------------------------------

    async def start_tcp(self, listen: Address, target: Address) -> Address:
        """Relay TCP connections from ``listen`` to ``target``; returns the bound address."""
        self._check_address("listen", listen)
        self._check_address("target", target)
        self._start_clock()

        async def on_connect(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
            task = asyncio.current_task()
            assert task is not None
            self._tcp_tasks.add(task)  # type: ignore[arg-type]
            try:
                await self._handle_tcp(reader, writer, target)
            except asyncio.CancelledError:
                # asyncio's stream server calls task.exception() on its handler tasks,
                # which logs a cancelled one as an error (Python 3.11).  When the relay
                # itself is closing, the cancellation is ours: end the task normally.
                if not self._closed:
                    raise
            finally:
                self._tcp_tasks.discard(task)  # type: ignore[arg-type]

        server = await asyncio.start_server(on_connect, listen[0], listen[1])
        self._servers.append(server)
        bound = server.sockets[0].getsockname()
        logger.info("relay tcp %s -> %s started", bound[:2], target)
        return (bound[0], bound[1])

    async def _handle_tcp(
        self, c_reader: asyncio.StreamReader, c_writer: asyncio.StreamWriter, target: Address
    ) -> None:
        peer = c_writer.get_extra_info("peername")
        try:
            s_reader, s_writer = await asyncio.open_connection(target[0], target[1])
        except OSError as exc:
            logger.warning("relay tcp %s: cannot connect to %s: %s", peer, target, exc)
            c_writer.close()
            return
        self._tcp_total += 1
        self._tcp_open += 1
        logger.info("relay tcp %s -> %s connected", peer, target)
        try:
            async with asyncio.TaskGroup() as tg:
                tg.create_task(self._pump(c_reader, s_writer, self._uplink, self._up))
                tg.create_task(self._pump(s_reader, c_writer, self._downlink, self._down))
        except* (ConnectionError, OSError) as eg:
            logger.info("relay tcp %s: closed: %s", peer, eg.exceptions[0])
        finally:
            self._tcp_open -= 1
            for w in (c_writer, s_writer):
                w.close()
            for w in (c_writer, s_writer):
                with contextlib.suppress(OSError, ConnectionError):
                    await w.wait_closed()

    async def _pump(
        self,
        reader: asyncio.StreamReader,
        writer: asyncio.StreamWriter,
        link: Link,
        counters: _Counters,
    ) -> None:
        loop = asyncio.get_running_loop()
        maxsize = max(1, min(TCP_MAX_QUEUED_SEGMENTS, link.spec.limit_packets // 2))
        queue: asyncio.Queue[tuple[float, bytes] | None] = asyncio.Queue(maxsize=maxsize)
        async with asyncio.TaskGroup() as tg:
            tg.create_task(self._tcp_writer(queue, writer, counters))
            last = -math.inf
            while True:
                data = await reader.read(_TCP_READ_BYTES)
                if not data:
                    break
                counters.bytes_in += len(data)
                for off in range(0, len(data), TCP_SEGMENT_BYTES):
                    seg = data[off : off + TCP_SEGMENT_BYTES]
                    counters.packets_in += 1
                    (d,) = self._send(link, loop.time(), len(seg) + TCP_OVERHEAD_BYTES, reliable=True)
                    last = max(last, d.time_s)
                    await queue.put((last, seg))
            await queue.put(None)

    async def _tcp_writer(
        self,
        queue: asyncio.Queue[tuple[float, bytes] | None],
        writer: asyncio.StreamWriter,
        counters: _Counters,
    ) -> None:
        loop = asyncio.get_running_loop()
        while True:
            item = await queue.get()
            if item is None:
                await writer.drain()
                if writer.can_write_eof():
                    writer.write_eof()
                return
            when, seg = item
            wait = when - loop.time()
            if wait > 0:
                await asyncio.sleep(wait)
            writer.write(seg)
            counters.packets_out += 1
            counters.bytes_out += len(seg)
            if queue.empty():
                await writer.drain()

    # -- lifecycle ----------------------------------------------------------------

    async def wait_tcp_idle(self, timeout_s: float = 1.0, poll_s: float = 0.02) -> bool:
        """Wait until no relayed TCP connection is open (both sides closed), at most ``timeout_s``; True if none is."""
        loop = asyncio.get_running_loop()
        end = loop.time() + timeout_s
        while self._tcp_open and loop.time() < end:
            await asyncio.sleep(poll_s)
        return self._tcp_open == 0

    async def close(self) -> None:
        """Stop listening, cancel TCP connections, drop what is still in flight."""
        if self._closed:
            return
        self._closed = True
        for server in self._servers:
            server.close()
        tasks = list(self._tcp_tasks)
        for task in tasks:
            task.cancel()
        if tasks:
            await asyncio.gather(*tasks, return_exceptions=True)
        for server in self._servers:
            await server.wait_closed()
        for line in self._delay_lines:
            line.close()
        for t in self._transports:
            t.close()
        logger.info("relay closed: %s", self.stats())

    async def __aenter__(self) -> Relay:
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.close()


async def serve_relay(
    path: PathSpec,
    seed: int,
    *,
    tcp: Sequence[tuple[Address, Address]] = (),
    udp: Sequence[tuple[Address, Address]] = (),
    allow_remote: bool = False,
    duration_s: float | None = None,
    stats_interval_s: float | None = None,
    on_stats: Callable[[RelayStats], None] | None = None,
) -> RelayStats:
    """Run a :class:`Relay` for the given (listen, target) pairs until cancelled.

    Stops after ``duration_s`` seconds when given; calls ``on_stats`` every
    ``stats_interval_s`` seconds and returns the final stats.
    """
    relay = Relay(path, seed, allow_remote=allow_remote)
    try:
        for listen, target in tcp:
            await relay.start_tcp(listen, target)
        for listen, target in udp:
            await relay.start_udp(listen, target)
        loop = asyncio.get_running_loop()
        deadline = None if duration_s is None else loop.time() + duration_s
        while True:
            step = stats_interval_s or 3600.0
            if deadline is not None:
                step = min(step, deadline - loop.time())
                if step <= 0:
                    break
            await asyncio.sleep(step)
            if on_stats is not None and stats_interval_s:
                on_stats(relay.stats())
    finally:
        await relay.close()
    return relay.stats()
