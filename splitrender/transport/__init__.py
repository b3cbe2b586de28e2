"""asyncio I/O shared by the live server and client: the TCP control channel.

The server and the client are peers at the same layer, so what both need to move
protocol bytes over a socket lives here rather than in one of them.
"""

from .control import ControlChannel, wall_us

__all__ = ["ControlChannel", "wall_us"]
