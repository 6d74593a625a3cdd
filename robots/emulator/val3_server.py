"""An emulator of a Staubli CS8/CS9 controller running the ROS-Industrial VAL 3 server
(`staubli_val3_driver`, val3/ros_server), on TCP, so a driver can be tested without a robot.

It reproduces the server's tasks (start.pgx) as threads: dataReceiver (motion port: reads a
JOINT_TRAJ_PT, queues it, replies), motionControl (hands queued points to the arm's movej),
dataStreamer (state port: JOINT_POSITION every period, STATUS every 5th) and recvHeartbeat (the
state port counts as connected a delay after a client connects). The receiver parses exactly as
the VAL 3 code does, quirks included: it reads a body only for JOINT_TRAJ_PT, so any other
message leaves its body in the stream to be read as the next header (the stream desynchronises),
and it resets its state machine when the next field of a message has not arrived yet (VAL 3
sioGet() does not wait for data), so a client must send each packet in one write. It accepts any
velocity above 0, as pushMotion.pgx does (`vel > 0` is its only check): a point at a velocity of
1e-38 is queued and holds the queue for ever, behind a move that never ends.

One client per port, and none can freeze a port or the emulator (clients.py: how the VAL 3
server's one-client sockets are followed, and where the emulator sets limits the VAL 3 code does
not have). The points received are kept for inspection, the newest `received_kept` of them.

Not emulated: JOINT_TRAJ_PT_FULL (14, read as an unknown type), interpolateVel.pgx's rewrite of a
0.1 % speed (a point with velocity exactly 0.001) and its rounding of the percentage to four
decimals (under 0.00005 % the speed becomes 0, which movej refuses with a task error; the emulated
arm moves at the tiny speed instead: the queue never drains either way), task errors
(error_code, in_error stay 0).
"""

from __future__ import annotations

import math
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from robots.arms.rx60 import ACCELERATION_TIME_S, RX60
from robots.drivers import simple_message as sm
from robots.drivers.simple_message import JointTrajPt, RobotStatus
from robots.emulator.arm import Arm, MoveJ
from robots.emulator.clients import ClientStalledError, Port

_RX60 = RX60()


@dataclass(frozen=True)
class EmulatorSettings:
    """Ports (0 = any free one), the VAL 3 tasks' periods (start.pgx) and the arm's limits."""

    host: str = "127.0.0.1"
    motion_port: int = 11000
    state_port: int = 11002
    joint_period_s: float = 0.02
    status_every: int = 5
    connect_delay_s: float = 1.0
    queue_depth: int = 10
    # The motion task's period; the receiver task has the same (start.pgx: 0.004 both).
    motion_period_s: float = 0.004
    # Emulated seconds per wall second of arm motion (tests move faster than real time).
    time_scale: float = 1.0
    lower_limits_rad: tuple[float, ...] = _RX60.lower_limits_rad
    upper_limits_rad: tuple[float, ...] = _RX60.upper_limits_rad
    nominal_speed_rad_s: tuple[float, ...] = _RX60.velocity_limits_rad_s
    acceleration_time_s: float = ACCELERATION_TIME_S
    # A client that leaves a field part-sent or takes nothing sent to it this long is dropped.
    client_timeout_s: float = 2.0
    # SO_SNDBUF of each client connection; 0: the system's (fault injection, see clients.py).
    send_buffer_bytes: int = 0
    # Received points kept for inspection (about 400 bytes each), the newest first to stay.
    received_kept: int = 10_000


class Val3Emulator:
    """The VAL 3 server on two loopback TCP ports, with an emulated arm and fault injection."""

    def __init__(
        self,
        settings: EmulatorSettings,
        q0: np.ndarray,
        on_joints: Callable[[np.ndarray], None] | None = None,
    ) -> None:
        self.settings = settings
        self._received: deque[JointTrajPt] = deque(maxlen=settings.received_kept)
        self.received_count = 0
        self._on_joints = on_joints
        speed_rad_s = np.array(settings.nominal_speed_rad_s)
        self._arm = Arm(q0, speed_rad_s, settings.acceleration_time_s, settings.queue_depth)
        self._queue: deque[MoveJ] = deque()  # qTrajPtBuffer
        self._lock = threading.Lock()
        self._stopping = threading.Event()
        self._threads: list[threading.Thread] = []
        self._motion: Port | None = None
        self._state: Port | None = None
        self._state_up = False  # nOutConnFlag == 1
        self._stop_now = False  # bStopNow
        self._e_stopped = False
        self._hold = False
        self._split = False
        self._stall_until_s = 0.0
        self._offset_rad = np.zeros(6)

    def start(self) -> Val3Emulator:
        s = self.settings
        limits = (s.client_timeout_s, s.send_buffer_bytes)
        self._motion = Port("motion", s.host, s.motion_port, *limits)
        self._state = Port("state", s.host, s.state_port, *limits)
        for task in (self._receiver, self._motion_control, self._state_port):
            thread = threading.Thread(target=task, name=f"val3-{task.__name__}", daemon=True)
            thread.start()
            self._threads.append(thread)
        return self

    def stop(self) -> None:
        self._stopping.set()
        for port in (self._motion, self._state):
            if port is not None:
                port.close()
        for thread in self._threads:
            thread.join(timeout=5.0)
        self._threads.clear()

    def __enter__(self) -> Val3Emulator:
        return self if self._threads else self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    @property
    def received(self) -> list[JointTrajPt]:
        """The points received, oldest first: the newest `received_kept` of them."""
        with self._lock:
            return list(self._received)

    @property
    def motion_address(self) -> tuple[str, int]:
        assert self._motion is not None, "start() the emulator first"
        return self._motion.listener.getsockname()[:2]

    @property
    def state_address(self) -> tuple[str, int]:
        assert self._state is not None, "start() the emulator first"
        return self._state.listener.getsockname()[:2]

    def joint_positions(self) -> np.ndarray:
        with self._lock:
            return self._arm.joints

    def status(self) -> RobotStatus:
        with self._lock:
            return self._status()

    def _status(self) -> RobotStatus:
        # fetchStatus.pgx: powered unless e-stopped; in_motion = not isSettled(); mode 2 = auto
        # (remote); motion_possible = powered and no e-stop and the tasks running.
        ok = 0 if self._e_stopped else 1
        return RobotStatus(ok, 1 - ok, 0, 0, int(self._arm.in_motion), 2, ok)

    def e_stop(self) -> None:
        """Emergency stop: the arm stops at once, queues are cleared, drives lose power."""
        with self._lock:
            self._e_stopped = True
            self._arm.stop()
            self._queue.clear()

    def reset_e_stop(self) -> None:
        with self._lock:
            self._e_stopped = False

    def drop_connections(self) -> None:
        """Close both clients; motionControl.pgx then stops the arm and clears the queues."""
        with self._lock:
            self._state_up = False
        for port in (self._motion, self._state):
            if port is not None:
                port.drop()

    def stall_state(self, seconds: float | None) -> None:
        """The state port stays connected but sends nothing for `seconds` (None: until
        resume_state())."""
        with self._lock:
            self._stall_until_s = math.inf if seconds is None else time.monotonic() + seconds

    def resume_state(self) -> None:
        with self._lock:
            self._stall_until_s = 0.0

    def set_split_writes(self, on: bool) -> None:
        """Send every packet in 1-3 byte TCP segments 1 ms apart."""
        self._split = on

    def set_reported_offset(self, offset_rad: np.ndarray) -> None:
        """Report joints = true joints + offset (measured joints leave the commanded path)."""
        offset_rad = np.array(offset_rad, dtype=float)
        if not np.isfinite(offset_rad).all():
            raise ValueError("the reported offset must be finite (the wire carries no NaN)")
        with self._lock:
            self._offset_rad = offset_rad

    def hold_queue(self, on: bool) -> None:
        """The motion task stops taking points from the queue (a blocked motion task)."""
        with self._lock:
            self._hold = on

    # --- the VAL 3 tasks -------------------------------------------------------------------
    def _receiver(self) -> None:
        """dataReceiver.pgx with recvMsgHeader / recvMsgBody / pushMotion / sendAck."""
        assert self._motion is not None
        port = self._motion
        while not self._stopping.is_set():
            sock = port.client
            try:
                ready = port.poll(sock, self.settings.motion_period_s)
                if port.listener in ready:
                    port.accept()
                    continue
                if sock is None or sock not in ready:
                    continue
                prefix = port.read(sock, sm.PREFIX.size, self._stopping)
                # The prefix's length is never used: the message type alone sets the body size.
                header = None if prefix is None else port.read(sock, sm.HEADER.size, self._stopping)
                if header is None:
                    continue
                msg_type, comm_type, _ = sm.HEADER.unpack(header)
                if msg_type != sm.JOINT_TRAJ_PT:
                    continue  # recvMsgBody.pgx: no body size, reset (the body stays unread)
                body = port.read(sock, sm.JOINT_TRAJ_PT_BODY.size, self._stopping)
                if body is None:
                    continue
                # decTrajPt.pgx checks no value; NaN and infinities are left to pushMotion.pgx.
                point = sm.decode_traj_pt(body, finite=False)
                reply_code = self._push_motion(point)
                if comm_type == sm.SERVICE_REQUEST:
                    reply = sm.encode_traj_pt_reply(point.sequence, reply_code)
                    port.send(sock, reply, self._split)
            except ClientStalledError as e:
                port.drop(sock, str(e))
            except (OSError, ValueError):
                # Lost, replaced or closed under us (ValueError: select on a closed socket).
                port.drop(sock)

    def _push_motion(self, point: JointTrajPt) -> int:
        """pushMotion.pgx: the reply code for a received point."""
        s = self.settings
        with self._lock:
            self._received.append(point)
            self.received_count += 1
            if point.sequence == sm.STOP_TRAJECTORY:
                self._stop_now = True
                return sm.SUCCESS
            speed_percent = float(np.clip(point.velocity * 100.0, 0.0, 100.0))
            q, lo, hi = point.joints_rad, s.lower_limits_rad, s.upper_limits_rad
            # isInRange() and `vel > 0`: a NaN or infinite joint and a NaN velocity fail them,
            # an infinite velocity is clipped to 100 % (as limit() does) and taken. Whether the
            # controller's fromBinary() decodes a NaN at all is not known here; if it does not,
            # decTrajPt.pgx fails and the reply is FAILURE as well.
            accept = bool(np.all((q >= lo) & (q <= hi))) and speed_percent > 0.0
            # The VAL 3 code has no e-stop check here; refusing while e-stopped is our choice.
            if accept and not self._e_stopped and len(self._queue) < s.queue_depth:
                self._queue.append(MoveJ(q, speed_percent))
                return sm.SUCCESS
            return sm.FAILURE

    def _motion_control(self) -> None:
        """motionControl.pgx: unless both ports are connected and no stop is asked, resetMotion()
        and clear the queues; else hand the next point to movej (blend off)."""
        assert self._motion is not None
        last_s = time.monotonic()
        while not self._stopping.wait(self.settings.motion_period_s):
            now_s = time.monotonic()
            dt_s, last_s = (now_s - last_s) * self.settings.time_scale, now_s
            with self._lock:
                connected = self._motion.client is not None and self._state_up
                if not connected or self._stop_now or self._e_stopped:
                    self._arm.stop()
                    self._queue.clear()
                    self._stop_now = False
                elif self._queue and not self._hold and self._arm.push(self._queue[0]):
                    self._queue.popleft()
                q = self._arm.step(dt_s)
            if self._on_joints is not None:
                self._on_joints(q)

    def _state_port(self) -> None:
        """recvHeartbeat.pgx and dataStreamer.pgx. The port counts as connected
        `connect_delay_s` after a client connects (delay(1.0)), as lost when the client goes or
        a write fails (sendData.pgx). While connected: JOINT_POSITION each period, and STATUS
        when the throttle count reaches `status_every`, i.e. after the 6th JOINT_POSITION, then
        every 5th (the count starts at 0 once and is never reset, not even on reconnection)."""
        assert self._state is not None
        port, period_s = self._state, self.settings.joint_period_s
        throttle, up_at_s, next_s = 0, math.inf, time.monotonic()
        while not self._stopping.is_set():
            sock = port.client
            try:
                ready = port.poll(sock, max(0.0, min(next_s, up_at_s) - time.monotonic()))
                if port.listener in ready:
                    port.accept()
                    up_at_s = time.monotonic() + self.settings.connect_delay_s
                    with self._lock:
                        self._state_up = False  # a new client: the delay again
                    continue
                if sock is not None and sock in ready and not sock.recv(256):
                    raise ConnectionError("the client closed the state connection")
                now_s = time.monotonic()
                if now_s >= up_at_s:
                    up_at_s = math.inf
                    with self._lock:
                        self._state_up = sock is not None and port.client is sock
                if now_s < next_s:
                    continue
                next_s = max(next_s + period_s, now_s)  # no burst to catch up after a delay
                with self._lock:
                    send = self._state_up and now_s >= self._stall_until_s
                    q_rad, status = self._arm.joints + self._offset_rad, self._status()
                if not send or sock is None:
                    continue
                packets = [sm.encode_joint_position(q_rad)]
                if throttle == self.settings.status_every:
                    packets.append(sm.encode_status(status))
                    throttle = 0
                throttle += 1
                for packet in packets:
                    port.send(sock, packet, self._split)
            except (OSError, ValueError) as e:
                with self._lock:
                    self._state_up = False
                port.drop(sock, str(e) if isinstance(e, ClientStalledError) else None)
