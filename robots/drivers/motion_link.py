"""The VAL 3 server's motion port as the driver uses it: one request, one matching reply.

The server answers each JOINT_TRAJ_PT service request with one reply echoing its sequence
(encTrajPtAck.pgx), in order, on one connection. A reply is taken only when it is the reply to
the request just sent: type JOINT_TRAJ_PT, comm type SERVICE_REPLY, the same sequence, a reply
code SUCCESS or FAILURE. Anything else (a reply with another sequence, a second reply to one
request, bytes when no request is waiting, a reply later than the timeout, bytes that are not a
packet) means the pairing of replies and requests can no longer be trusted: the link sends the
stop (sequence -4) without waiting for its reply and closes the connection, on which the server
also stops (motionControl.pgx resets motion when the motion port is lost). The next request
opens a new connection, so a stray reply is never read as the answer to a later request.
"""

from __future__ import annotations

import contextlib
import select
import socket
import time
from collections.abc import Callable

import numpy as np

from reconstruction.common.errors import ScannerError
from robots.drivers import simple_message as sm
from robots.drivers.simple_message import close_socket

STOP = sm.JointTrajPt(sm.STOP_TRAJECTORY, np.zeros(6), 0.0, 0.0)


class MotionLinkError(Exception):
    """The motion port failed or answered out of step (one line); the connection is closed."""


class MotionLink:
    """The motion connection: `connect` opens it (raising what it raises), `reply_timeout_s`
    bounds the wait for each reply, `where` names it in messages."""

    def __init__(
        self, connect: Callable[[], socket.socket], reply_timeout_s: float, where: str
    ) -> None:
        self._connect = connect
        self._reply_timeout_s = reply_timeout_s
        self._where = where
        self._sock: socket.socket | None = None

    def open(self) -> None:
        if self._sock is None:
            self._sock = self._connect()

    def request(self, point: sm.JointTrajPt) -> int:
        """Send `point`, return the reply code of its reply (SUCCESS or FAILURE)."""
        try:
            self.open()
        except (ScannerError, OSError) as e:
            raise MotionLinkError(
                f"cannot reopen the motion connection {self._where} ({e})"
            ) from None
        self.check_quiet()
        sock = self._sock
        deadline_s = time.monotonic() + self._reply_timeout_s
        try:
            sock.settimeout(self._reply_timeout_s)
            sock.sendall(sm.encode_traj_pt(point))
            header, body = sm.read_packet(sock, {sm.JOINT_TRAJ_PT}, deadline_s)
            reply = sm.decode_traj_pt(body)
        except TimeoutError:
            self._abandon()
            raise MotionLinkError(
                f"no reply to point {point.sequence} from {self._where} within "
                f"{self._reply_timeout_s} s"
            ) from None
        except OSError as e:
            self._abandon()
            raise MotionLinkError(f"motion connection {self._where} failed ({e})") from None
        except sm.ProtocolError as e:
            self._abandon()
            raise MotionLinkError(f"motion connection {self._where}: {e}") from None
        mismatch = _mismatch(point, header, reply)
        if mismatch is not None:
            self._abandon()
            raise MotionLinkError(f"{self._where} {mismatch}")
        return header.reply_code

    def check_quiet(self) -> None:
        """Between requests the server has nothing to say: bytes now are a reply to no request
        (a duplicate, or a reply that came after its timeout); the end of the stream is a lost
        connection."""
        sock = self._sock
        if sock is None or not select.select([sock], [], [], 0.0)[0]:
            return
        try:
            unasked = sock.recv(1, socket.MSG_PEEK)
        except OSError as e:
            unasked, lost = b"", str(e)
        else:
            lost = "closed by the other end"
        self._abandon()
        if unasked:
            raise MotionLinkError(f"{self._where} sent a reply to no request")
        raise MotionLinkError(f"motion connection {self._where} lost ({lost})")

    def stop(self) -> None:
        """Stop the arm and clear the controller's queue (sequence -4); best effort. A link
        already abandoned sent its stop then, and its connection is closed."""
        if self._sock is None:
            return
        with contextlib.suppress(MotionLinkError):
            self.request(STOP)

    def _abandon(self) -> None:
        """The stop, not waiting for its reply, then the connection closed."""
        sock, self._sock = self._sock, None
        if sock is None:
            return
        with contextlib.suppress(OSError):
            sock.settimeout(self._reply_timeout_s)
            sock.sendall(sm.encode_traj_pt(STOP))
        close_socket(sock)

    def close(self) -> None:
        sock, self._sock = self._sock, None
        if sock is not None:
            close_socket(sock)


def _mismatch(point: sm.JointTrajPt, header: sm.Header, reply: sm.JointTrajPt) -> str | None:
    """Why this packet is not the reply to `point`, or None."""
    if header.comm_type != sm.SERVICE_REPLY:
        return f"sent comm type {header.comm_type} where point {point.sequence}'s reply was due"
    if reply.sequence != point.sequence:
        return f"answered point {point.sequence} with the reply to point {reply.sequence}"
    if header.reply_code not in (sm.SUCCESS, sm.FAILURE):
        return f"answered point {point.sequence} with reply code {header.reply_code}"
    return None
