"""The emulator's TCP ports: one client at a time on each, and no client can freeze a port.

The VAL 3 server reads and writes each port through one sio socket, configured on the
controller as a TCP server (staubli_val3_driver README), and serves one client on it. The
emulator follows that: one client per port, and a new connection replaces the current one, which
is closed, so a driver reconnecting after a crash is served at once.

Where the VAL 3 code waits without limit, the emulator does not: recvData.pgx waits for the rest
of a field once its first byte has come, and sioSet() blocks while the client does not read. A
client that leaves a field part-sent, or does not take what is sent to it, for longer than
`client_timeout_s` is dropped here, and the drop is logged (logger "robots.emulator"); a new
connection is accepted during those waits, so no client waits behind one that stalls.
"""

from __future__ import annotations

import logging
import select
import socket
import threading
import time

from robots.drivers.simple_message import close_socket

log = logging.getLogger("robots.emulator")
# Fault injection: split writes go out in pieces of 1, 2, 3, 1, ... bytes, this far apart.
_SPLIT_PAUSE_S = 0.001
# How often a wait for the rest of a field looks at the listener and the emulator's stop.
_WAIT_S = 0.05


class ClientStalledError(ConnectionError):
    """The client held a read or a write longer than the limit."""


class ClientReplacedError(ConnectionError):
    """A new client took the port while the current one's message was being read."""


class Port:
    """A listening TCP port with at most one client. `name` labels the log; `client_timeout_s`
    bounds every wait on the client; `send_buffer_bytes` > 0 sets the client socket's send
    buffer (fault injection: a client that stops reading fills a small one within seconds)."""

    def __init__(
        self,
        name: str,
        host: str,
        port: int,
        client_timeout_s: float,
        send_buffer_bytes: int = 0,
    ) -> None:
        self.name = name
        self.listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self.listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.listener.bind((host, port))
        self.listener.listen(1)
        self.client: socket.socket | None = None
        self._timeout_s = client_timeout_s
        self._send_buffer_bytes = send_buffer_bytes
        self._lock = threading.Lock()

    def accept(self) -> socket.socket:
        sock, _ = self.listener.accept()
        # The controller's sockets are configured with Nagle off (staubli_val3_driver README).
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        if self._send_buffer_bytes > 0:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, self._send_buffer_bytes)
        with self._lock:
            old, self.client = self.client, sock
        if old is not None:
            log.info("%s port: a new client replaces %s", self.name, _peer(old))
            close_socket(old)
        return sock

    def drop(self, sock: socket.socket | None = None, why: str | None = None) -> None:
        """Close the client (only if it is still `sock`, when given); log `why` when given."""
        with self._lock:
            if sock is not None and sock is not self.client:
                return
            old, self.client = self.client, None
        if old is not None:
            if why is not None:
                log.warning("%s port: dropped the client %s: %s", self.name, _peer(old), why)
            close_socket(old)

    def poll(self, sock: socket.socket | None, timeout_s: float) -> list[socket.socket]:
        """Wait for a connection on the listener or data (or the end) from `sock`."""
        watched = [self.listener] if sock is None else [self.listener, sock]
        return select.select(watched, [], [], timeout_s)[0]

    def read(self, sock: socket.socket, count: int, stopping: threading.Event) -> bytes | None:
        """recvData.pgx: None when not one byte is there yet (sioGet() returns 0 and the state
        machine resets); once a byte came, the rest of the `count` bytes, waited for at most
        client_timeout_s (ClientStalledError), or until a new client takes the port
        (ClientReplacedError)."""
        data, deadline_s = b"", None
        while len(data) < count:
            if stopping.is_set():
                raise ConnectionError("the emulator is stopping")
            if deadline_s is None:
                ready = select.select([sock], [], [], 0.0)[0]
                if not ready:
                    return None
            else:
                left_s = deadline_s - time.monotonic()
                if left_s <= 0:
                    raise ClientStalledError(
                        f"{len(data)} of {count} bytes of a field in {self._timeout_s} s"
                    )
                ready = self.poll(sock, min(_WAIT_S, left_s))
                if self.listener in ready:
                    self.accept()
                    raise ClientReplacedError("a new client took the port")
                if sock not in ready:
                    continue
            chunk = sock.recv(count - len(data))
            if not chunk:
                raise ConnectionError(f"the client closed the {self.name} connection")
            if deadline_s is None:
                deadline_s = time.monotonic() + self._timeout_s
            data += chunk
        return data

    def send(self, sock: socket.socket, packet: bytes, split: bool = False) -> None:
        """sendRosMsg.pgx: prefix, header and body as three writes, all taken by the client
        within client_timeout_s (ClientStalledError); with `split`, in 1-3 byte pieces 1 ms
        apart."""
        deadline_s = time.monotonic() + self._timeout_s
        for part in (packet[:4], packet[4:16], packet[16:]):
            pieces, i, size = [], 0, 1
            while split and i < len(part):
                pieces.append(part[i : i + size])
                i, size = i + size, size % 3 + 1
            for piece in pieces or [part]:
                left_s = deadline_s - time.monotonic()
                try:
                    if left_s <= 0:
                        raise TimeoutError
                    sock.settimeout(left_s)
                    sock.sendall(piece)
                except TimeoutError:
                    raise ClientStalledError(
                        f"it took no {len(packet)}-byte message in {self._timeout_s} s"
                    ) from None
                if split:
                    time.sleep(_SPLIT_PAUSE_S)

    def close(self) -> None:
        self.drop()
        close_socket(self.listener)


def _peer(sock: socket.socket) -> str:
    try:
        host, port = sock.getpeername()[:2]
    except OSError:
        return "(gone)"
    return f"{host}:{port}"
