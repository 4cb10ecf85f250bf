"""Where the live view listens: loopback only, Foxglove's usual port (no foxglove import)."""

from __future__ import annotations

import socket

LIVE_HOST = "127.0.0.1"  # the live view never listens beyond this machine
DEFAULT_PORT = 8765  # Foxglove's usual WebSocket port


def port_is_free(port: int, host: str = LIVE_HOST) -> bool:
    """Whether a TCP server could bind ``host:port`` now (0: any free port, always True)."""
    if port == 0:
        return True
    with socket.socket() as probe:
        try:
            probe.bind((host, port))
        except OSError:
            return False
    return True
