"""A scripted VAL 3 server that lies to the driver on purpose (the fault-injection suite's peer).

Unlike the emulator, which behaves as the real server does, this fake does what a test tells it:
its arm jumps from point to point (one accepted point every `step_s`, 10 queued at most, FAILURE
when full), it streams JOINT_POSITION every `joint_period_s` and STATUS every `status_every`-th
time, and a test changes any of that mid-motion: `answer` decides what each request gets back
(late, twice, with another sequence, raw bytes, nothing), `joints_wire` overrides the joints it
streams (NaN included: it packs them itself, the codec would refuse them), `send_joints` and
`send_status` pause either stream, `state_inject` sends raw bytes on it, `state_hang_up` closes
it. It records every request with its arrival time and connection, and when each STATUS went
out, so a test asserts what was sent after a fault and how long the driver took to see it.
"""

from __future__ import annotations

import contextlib
import socket
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from robots.drivers import simple_message as sm

QUEUE_DEPTH = 10


@dataclass(frozen=True, eq=False)
class Request:
    """A JOINT_TRAJ_PT the fake received: when (monotonic s), on which motion connection."""

    at_s: float
    connection: int
    point: sm.JointTrajPt


# What a request gets back: (delay before sending in s, bytes) pairs, in order.
Answer = list[tuple[float, bytes]]


def reply(sequence: int, code: int = sm.SUCCESS) -> bytes:
    return sm.encode_traj_pt_reply(sequence, code)


def reply_code(packet: bytes) -> int:
    return sm.HEADER.unpack_from(packet, sm.PREFIX.size)[2]


def raw_joint_position(joints: list[float]) -> bytes:
    """A JOINT_POSITION packed without the codec's checks (it may carry NaN)."""
    body = sm.JOINT_POSITION_BODY.pack(0, *(list(joints) + [0.0] * (10 - len(joints))))
    return sm.packet(sm.Header(sm.JOINT_POSITION, sm.TOPIC, sm.INVALID), body)


class FakeController:
    def __init__(
        self,
        q0: np.ndarray,
        step_s: float = 0.02,
        joint_period_s: float = 0.02,
        status_every: int = 5,
    ) -> None:
        self.q_rad = np.array(q0, float)
        self.status = sm.RobotStatus(1, 0, 0, 0, 0, 2, 1)
        self.step_s, self.joint_period_s, self.status_every = step_s, joint_period_s, status_every
        self.requests: list[Request] = []
        self.status_sent_at: list[float] = []
        self.closed_connections: list[int] = []
        self.joints_wire: list[float] | None = None
        self.offset_rad = np.zeros(6)
        self.send_joints = True
        self.send_status = True
        self.state_inject: bytes | None = None  # sent once, in place of the next joints
        self.state_hang_up = False
        self.hold = False  # the arm takes no point from the queue
        self.refuse_all = False
        self.answer: Callable[[Request, bytes], Answer] = lambda request, normal: [(0.0, normal)]
        self.fault_at_s: float | None = None
        self._queue: deque[np.ndarray] = deque()
        self._lock = threading.Lock()
        self._stopping = threading.Event()
        self._motion = socket.create_server(("127.0.0.1", 0))
        self._state = socket.create_server(("127.0.0.1", 0))
        self._sockets: list[socket.socket] = [self._motion, self._state]
        threads = [
            (self._serve, (self._motion, self._serve_client)),
            (self._serve, (self._state, self._stream)),
            (self._move, ()),
        ]
        for target, args in threads:
            threading.Thread(target=target, args=args, daemon=True).start()

    @property
    def ports(self) -> tuple[int, int]:
        return self._motion.getsockname()[1], self._state.getsockname()[1]

    def fault(self) -> None:
        """Record the moment the fault was applied."""
        self.fault_at_s = time.monotonic()

    def fault_at(self, at: int | Callable[[Request], bool], fault: Callable) -> None:
        """Answer the request `at` (a sequence number, or a test of the request) with
        `fault(request, normal)`, recording the fault's moment, unless that returns None (not
        this time: the normal reply); every other request gets the normal reply."""
        chosen = at if callable(at) else lambda request: request.point.sequence == at

        def answer(request: Request, normal: bytes) -> Answer:
            faulty = fault(request, normal) if chosen(request) else None
            if faulty is None:
                return [(0.0, normal)]
            self.fault()
            return faulty

        self.answer = answer

    def sent_after(self, t_s: float, closed: int | None = None) -> list[int]:
        """The sequence numbers the driver sent after t_s; with `closed`, once the driver has
        closed that motion connection (everything it sent on it has then been read), and an
        AssertionError if it has not within a second."""
        deadline_s = time.monotonic() + 1.0
        while closed is not None and closed not in self.closed_connections:
            assert time.monotonic() < deadline_s, f"motion connection {closed} is still open"
            time.sleep(0.005)
        with self._lock:
            return [r.point.sequence for r in self.requests if r.at_s > t_s]

    def points(self) -> list[sm.JointTrajPt]:
        with self._lock:
            return [r.point for r in self.requests if r.point.sequence >= 0]

    def close(self) -> None:
        self._stopping.set()
        for sock in self._sockets:
            with contextlib.suppress(OSError):
                sock.shutdown(socket.SHUT_RDWR)
            sock.close()

    def __enter__(self) -> FakeController:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- the arm ------------------------------------------------------------------------------

    def _move(self) -> None:
        while not self._stopping.wait(self.step_s):
            with self._lock:
                if self._queue and not self.hold:
                    self.q_rad = self._queue.popleft()

    def _accept(self, point: sm.JointTrajPt) -> int:
        with self._lock:
            if point.sequence == sm.STOP_TRAJECTORY:
                self._queue.clear()
                return sm.SUCCESS
            if self.refuse_all or len(self._queue) >= QUEUE_DEPTH:
                return sm.FAILURE
            self._queue.append(np.array(point.joints_rad, float))
            return sm.SUCCESS

    # -- the ports ----------------------------------------------------------------------------

    def _serve(self, listener: socket.socket, handle: Callable[[socket.socket, int], None]):
        """Each connection to `listener` handled by `handle(conn, its number: 1, 2, ...)` in a
        thread of its own."""
        number = 0
        while not self._stopping.is_set():
            try:
                conn, _ = listener.accept()
            except OSError:
                return
            number += 1
            self._sockets.append(conn)
            threading.Thread(target=handle, args=(conn, number), daemon=True).start()

    def _serve_client(self, conn: socket.socket, connection: int) -> None:
        try:
            while True:
                _, body = sm.read_packet(conn, {sm.JOINT_TRAJ_PT})
                point = sm.decode_traj_pt(body)
                request = Request(time.monotonic(), connection, point)
                with self._lock:
                    self.requests.append(request)
                normal = reply(point.sequence, self._accept(point))
                for delay_s, packet in self.answer(request, normal):
                    time.sleep(delay_s)
                    conn.sendall(packet)
        except (OSError, sm.ProtocolError):
            conn.close()
            with self._lock:
                self.closed_connections.append(connection)

    def _stream(self, conn: socket.socket, _connection: int) -> None:
        count = 0
        try:
            while not self._stopping.wait(self.joint_period_s):
                with self._lock:
                    q = self.q_rad + self.offset_rad
                    wire = self.joints_wire
                    status = replace(self.status, in_motion=int(bool(self._queue)))
                    inject, self.state_inject = self.state_inject, None
                if self.state_hang_up:
                    conn.close()
                    return
                if inject is not None:
                    conn.sendall(inject)
                elif self.send_joints:
                    conn.sendall(raw_joint_position(list(q) if wire is None else wire))
                count += 1
                if count % self.status_every == 0 and self.send_status:
                    conn.sendall(sm.encode_status(status))
                    self.status_sent_at.append(time.monotonic())
        except OSError:
            pass
