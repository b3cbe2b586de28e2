"""asyncio I/O shared by the live server and client: the TCP control channel and
the socket errors both report.

The server and the client are peers at the same layer, so what both need to move
protocol bytes over a socket lives here rather than in one of them.
"""

from .control import ControlChannel, wall_us
from .errors import BindError, ConnectError, describe_os_error

__all__ = ["BindError", "ConnectError", "ControlChannel", "describe_os_error", "wall_us"]
