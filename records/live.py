"""Where the live view listens: loopback only, Foxglove's usual port (no foxglove import)."""

from __future__ import annotations

import socket

import click

LIVE_HOST = "127.0.0.1"  # the live view never listens beyond this machine
DEFAULT_PORT = 8765  # Foxglove's usual WebSocket port

# ``covswarm coordinator --foxglove`` and ``covswarm run --foxglove`` (passed on to it).
FOXGLOVE_OPTION = click.option(
    "--foxglove",
    "foxglove_port",
    type=click.IntRange(0, 65535),
    is_flag=False,
    flag_value=DEFAULT_PORT,
    default=None,
    help=f"Live view: the coordinator serves the run's channels to Foxglove on "
    f"ws://{LIVE_HOST}:PORT [{DEFAULT_PORT} without a port; 0 picks a free one] "
    f"(docs/records.md).",
)


def port_is_free(port: int, host: str = LIVE_HOST) -> bool:
    """Whether a TCP server could bind ``host:port`` now (0: any free port, always True).

    The probe sets SO_REUSEADDR as the servers do (tokio under foxglove-sdk, aiohttp): a
    connection the last run's server closed lingers in TIME-WAIT on that port for up to a
    minute, which a plain bind counts as "in use" though nothing listens; with the option
    only a live socket bound to the port (a listener) refuses it, on Linux."""
    if port == 0:
        return True
    with socket.socket() as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            probe.bind((host, port))
        except OSError:
            return False
    return True
