"""Asyncio wrapper around the sans-IO control connection (TCP), shared by server and client.

Bytes from the stream reader are handed to :class:`~splitrender.protocol.Connection`,
messages come out; writes go through one lock and ``drain()`` (hypercorn habit), so
messages from several tasks never interleave on the wire and a slow peer pushes back.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import AsyncIterator

from splitrender.errors import LocalProtocolError, RemoteProtocolError
from splitrender.protocol import CONNECTION_CLOSED, NEED_DATA, Connection, Error, Message

__all__ = ["ControlChannel", "READ_CHUNK_BYTES", "wall_ms", "wall_us"]

logger = logging.getLogger(__name__)

READ_CHUNK_BYTES = 65536
"""Bytes asked of the stream reader per read."""


def wall_us() -> int:
    """The host wall clock (``time.time``) in integer µs: the protocol's clock.

    Live sessions assume server and client wall clocks agree (same host, or NTP):
    ``Pose.t_us``, ``FrameMeta.t_us`` and ``Feedback`` times are all on it.
    """
    return time.time_ns() // 1000


def wall_ms() -> float:
    """The live front doors' clock for the session cores (their ``now_ms``): the host wall clock, the protocol's, in
    ms."""
    return time.time() * 1000


class ControlChannel:
    """One TCP control connection: ``send(msg)`` and ``async for msg in channel``.

    ``log_id`` (a session id or address) prefixes every log line.
    """

    def __init__(self, conn: Connection, reader: asyncio.StreamReader, writer: asyncio.StreamWriter,
                 log_id: str = "") -> None:
        self.conn = conn
        self.reader = reader
        self.writer = writer
        self.log_id = log_id
        self._lock = asyncio.Lock()
        self.bytes_sent = 0
        self.bytes_received = 0

    @property
    def write_buffer_bytes(self) -> int:
        """Bytes queued in the transport but not yet handed to the kernel."""
        transport = self.writer.transport
        return 0 if transport.is_closing() else transport.get_write_buffer_size()

    async def send(self, msg: Message, drain: bool = True) -> None:
        """Frame and write ``msg`` (under the write lock); raises ``LocalProtocolError``
        if the session state forbids it and ``ConnectionError`` if the peer is gone."""
        async with self._lock:
            data = self.conn.send(msg)
            if self.writer.is_closing():
                raise ConnectionResetError("control connection is closed")
            self.writer.write(data)
            self.bytes_sent += len(data)
            if drain:
                await self.writer.drain()

    async def write_frames(self, frames: list[bytes], drain: bool = True) -> None:
        """Write control frames already framed by ``self.conn`` (the pipeline frames and counts them)."""
        async with self._lock:
            if self.writer.is_closing():
                raise ConnectionResetError("control connection is closed")
            for data in frames:
                self.writer.write(data)
                self.bytes_sent += len(data)
            if drain:
                await self.writer.drain()

    async def send_error(self, exc: RemoteProtocolError | int, text: str = "") -> None:
        """Best-effort ``Error`` message (ignores a peer that is already gone)."""
        try:
            async with self._lock:
                data = self.conn.send_error(exc, text)
                if not self.writer.is_closing():
                    self.writer.write(data)
                    await asyncio.wait_for(self.writer.drain(), 1.0)
        except (ConnectionError, LocalProtocolError, asyncio.TimeoutError) as err:
            logger.debug("%s: could not send Error: %s", self.log_id, err)

    async def next_message(self) -> Message | None:
        """The next peer message, or ``None`` after a clean EOF.

        Raises a ``RemoteProtocolError`` subclass on malformed or illegal input.
        """
        while True:
            event = self.conn.next_event()
            if event is CONNECTION_CLOSED:
                return None
            if event is NEED_DATA:
                data = await self.reader.read(READ_CHUNK_BYTES)
                self.bytes_received += len(data)
                self.conn.receive_data(data)
                continue
            assert isinstance(event, Message)
            return event

    async def messages(self) -> AsyncIterator[Message]:
        """Peer messages until a clean EOF (see :meth:`next_message`)."""
        while (msg := await self.next_message()) is not None:
            yield msg

    async def close(self) -> None:
        """Close the socket and wait (briefly) until it is closed."""
        self.writer.close()
        try:
            await asyncio.wait_for(self.writer.wait_closed(), 1.0)
        except (ConnectionError, asyncio.TimeoutError):
            pass

    @staticmethod
    def error_message(msg: Error) -> str:
        """``"413: text"`` for logs and exceptions."""
        return f"{msg.code}: {msg.text}"
