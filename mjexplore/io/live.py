"""Live view of an episode in Foxglove: a Foxglove WebSocket server on the episode's topics.

The :class:`~mjexplore.io.mcap_log.FoxgloveEpisodeLog` logs to the server's context, so the
live topics are those of the episode MCAP, built by the same code. In Foxglove: "Open
connection", "Foxglove WebSocket", ``ws://127.0.0.1:8765``.

The simulation runs faster than real time; ``rate`` paces it (simulated seconds per
wall-clock second) so that a viewer can follow, and ``wait`` holds the episode until a client
subscribes, so that a viewer sees it from the start. The server's time (Foxglove's current
time) is the simulated time of the last scan.
"""

from __future__ import annotations

import ipaddress
import logging
import socket
import threading
import time

import foxglove
from foxglove.websocket import Capability, ServerListener

from mjexplore.errors import UserInputError
from mjexplore.io.stamps import sim_ns

log = logging.getLogger(__name__)

DEFAULT_PORT = 8765
DEFAULT_HOST = "127.0.0.1"


HOST_HINT = "127.0.0.1 (this machine only) or 0.0.0.0 (every interface)"


def check_host(host: str) -> None:
    """Refuses an address a server cannot bind here: one that is not an IP address or a
    host name that resolves (``256.1.1.1``), or an address of another machine.

    Raises:
        UserInputError: with the addresses to use instead.
    """
    try:
        ipaddress.ip_address(host)
    except ValueError:
        # Dotted numbers or a colon are meant as an address: no name lookup for them.
        if not host or ":" in host or all(c.isdigit() or c == "." for c in host):
            raise UserInputError(f"--live-host {host!r} is not a valid IP address: give an "
                                 f"address of this machine, e.g. {HOST_HINT}.") from None
    try:
        family, kind, proto, _, address = socket.getaddrinfo(
            host, 0, type=socket.SOCK_STREAM)[0]
    except (OSError, UnicodeError) as exc:
        reason = getattr(exc, "strerror", None) or str(exc)
        raise UserInputError(f"--live-host {host!r} is not a valid address ({reason}): give "
                             f"an address of this machine, e.g. {HOST_HINT}.") from None
    with socket.socket(family, kind, proto) as probe:
        try:
            probe.bind(address)  # Port 0: tests the address, not a port.
        except OSError as exc:
            raise UserInputError(
                f"--live-host {host!r} is not an address of this machine ({exc.strerror}): "
                f"the live server listens on one of its own interfaces: give {HOST_HINT}.") \
                from None


class LiveServer(ServerListener):
    """A started Foxglove WebSocket server; stop it with :meth:`stop` (or use ``with``).

    Args:
        host: Address to bind; the loopback interface by default (other machines cannot
            connect). ``0.0.0.0`` serves every interface.
        port: TCP port; 0 takes a free one (see :attr:`port`).
        rate: Simulated seconds per wall-clock second to pace the episode at (1.0: real
            time), or None to run as fast as it can.
        wait: Hold the episode (:meth:`wait_for_subscriber`) until a client subscribes to
            a topic.

    Raises:
        UserInputError: The port is taken, the address is not valid or not this
            machine's (:func:`check_host`), or ``rate`` is not positive.
    """

    def __init__(self, host: str = DEFAULT_HOST, port: int = DEFAULT_PORT,
                 rate: float | None = None, wait: bool = False) -> None:
        if rate is not None and not rate > 0:
            raise UserInputError(f"--live-rate {rate} must be positive (1 is real time).")
        self.host, self.rate, self.wait = host, rate, wait
        self.context = foxglove.Context()
        self._start = threading.Event()  # Set by a subscription or stop: the episode may go.
        # The server object takes one call at a time (another thread's raises RuntimeError).
        self._lock = threading.Lock()
        self._wall0: float | None = None  # Wall-clock time at the first paced scan.
        check_host(host)  # Before the bind, whose error would blame the port.
        try:
            self.server = foxglove.start_server(
                name="mjexplore", host=host, port=port, context=self.context,
                capabilities=[Capability.Time], server_listener=self)
        except RuntimeError as exc:
            raise UserInputError(
                f"cannot serve Foxglove on {host}:{port} ({exc}): give a free port, e.g. "
                "--live 8766, or stop what uses it.") from None
        self.port = self.server.port
        log.info("Foxglove live server on %s", self.url)

    @property
    def url(self) -> str:
        """What to open in Foxglove ("Open connection", "Foxglove WebSocket")."""
        return f"ws://{self.host}:{self.port}"

    def on_subscribe(self, client, channel) -> None:
        self._start.set()

    def wait_for_subscriber(self) -> None:
        """Returns once a client has subscribed to a topic or the server is stopped (at once
        unless ``wait``). Ctrl-C ends the wait with KeyboardInterrupt."""
        if not self.wait:
            return
        log.info("waiting for a Foxglove client on %s", self.url)
        while not self._start.wait(0.25):  # Short waits: Ctrl-C gets through.
            pass

    def pace(self, t: float) -> None:
        """Tells clients the simulated time ``t`` (seconds) and, with ``rate``, sleeps until
        the wall clock has caught up with it."""
        with self._lock:
            self.server.broadcast_time(sim_ns(t))
        if self.rate is None:
            return
        now = time.monotonic()
        if self._wall0 is None:
            self._wall0 = now - t / self.rate
        time.sleep(max(0.0, self._wall0 + t / self.rate - now))

    def stop(self) -> None:
        """Stops the server (again: no effect) and disconnects its clients."""
        with self._lock:
            self.server.stop()
        self._start.set()  # Nobody can subscribe now.

    def __enter__(self) -> LiveServer:
        return self

    def __exit__(self, *exc) -> None:
        self.stop()
