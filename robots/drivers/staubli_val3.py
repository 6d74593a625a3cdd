"""The RX60 through its controller: a client of the ROS-Industrial VAL 3 server (CS8/CS9).

The server (ros-industrial/staubli_val3_driver) listens on two TCP ports: motion (11000), where it
reads JOINT_TRAJ_PT service requests and answers each, and state (11002), where it streams
JOINT_POSITION every 20 ms and STATUS every 100 ms. It moves only while both are connected; it
runs each point as a `movej` (straight in joint space, blending off: the arm stops at every
point) at the point's speed fraction, from a 10-deep queue (FAILURE when full: resend later).

So the driver takes only trajectories whose joint-linear path was checked
(`JointTrajectory.joint_linear`, see planners/joint_linear.py) and streams exactly their
positions. It refuses to move while STATUS says e-stopped, drives off, in error or motion not
possible; it stops the arm (sequence -4) and raises RobotStoppedError when the state stream is
silent for longer than state_timeout_s, a connection drops, STATUS turns bad, or the measured
joints leave the commanded path by more than path_tolerance_rad. The scan then ends as
interrupted (resumable) with every capture kept.
"""

from __future__ import annotations

import contextlib
import socket
import threading
import time
from dataclasses import dataclass

import numpy as np

from reconstruction.common.errors import ScannerError
from robots.drivers import simple_message as sm
from robots.drivers.interfaces import JointTrajectory, RobotDriver
from robots.drivers.settings import RobotLinkConfig

# industrial_robot_client's streamer: a point is reached when every joint is within this of it.
ARRIVAL_TOLERANCE_RAD = 0.005
# How long the motion port may take to answer one point.
REPLY_TIMEOUT_S = 2.0
# A refused point is resent this often while the queue drains (FAILURE: queue full).
RESEND_PERIOD_S = 0.02


class RobotStoppedError(ScannerError):
    """The arm did not move (the controller cannot) or was stopped (the link or the controller
    failed during a motion); the scan ends as interrupted and can be resumed. Exit code 5."""

    exit_code = 5


@dataclass(frozen=True, eq=False)
class RobotState:
    """The newest state the controller streamed, and when it arrived (monotonic seconds)."""

    joints_rad: np.ndarray | None
    status: sm.RobotStatus | None
    joints_at_s: float
    status_at_s: float


class Val3Robot(RobotDriver):
    motion = "joint_linear"

    def __init__(self, settings: RobotLinkConfig) -> None:
        self.settings = settings
        self._lock = threading.Condition()
        self._state = RobotState(None, None, 0.0, 0.0)
        self._link_error: str | None = None
        self._sequence = 0
        self._closed = False
        self._motion = self._connect(settings.motion_port, "motion_port")
        try:
            self._state_socket = self._connect(settings.state_port, "state_port")
        except ScannerError:
            self._motion.close()
            raise
        self._reader = threading.Thread(target=self._read_state, daemon=True, name="val3-state")
        self._reader.start()
        self._wait_first_state()

    # -- connection -------------------------------------------------------------------------

    def _where(self, port: int) -> str:
        return f"{self.settings.host}:{port}"

    def _connect(self, port: int, field: str) -> socket.socket:
        try:
            sock = socket.create_connection(
                (self.settings.host, port), timeout=self.settings.connect_timeout_s
            )
        except OSError as e:
            raise ScannerError(
                f"hardware.robot.{field}: cannot connect to {self._where(port)} "
                f"({e.strerror or e}); expected the VAL 3 ROS server of the arm's controller"
            ) from None
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        return sock

    def _wait_first_state(self) -> None:
        # The server starts streaming 1 s after the state port connects (recvHeartbeat.pgx).
        deadline = time.monotonic() + self.settings.connect_timeout_s + 1.0
        with self._lock:
            while self._link_error is None and (
                self._state.joints_rad is None or self._state.status is None
            ):
                left = deadline - time.monotonic()
                if left <= 0:
                    break
                self._lock.wait(left)
            error, state = self._link_error, self._state
        if error is not None or state.joints_rad is None or state.status is None:
            self.close()
            what = error or "no joint state and status within the timeout"
            raise ScannerError(
                f"hardware.robot.state_port: {self._where(self.settings.state_port)} did not "
                f"stream the VAL 3 server's state ({what})"
            )

    def _read_state(self) -> None:
        """Only reads: the server takes any byte on the state port as a heartbeat."""
        self._state_socket.settimeout(None)
        try:
            while True:
                header, body = sm.read_packet(self._state_socket, {sm.JOINT_POSITION, sm.STATUS})
                now = time.monotonic()
                with self._lock:
                    s = self._state
                    if header.msg_type == sm.JOINT_POSITION:
                        q = sm.decode_joint_position(body)
                        self._state = RobotState(q, s.status, now, s.status_at_s)
                    else:
                        status = sm.decode_status(body)
                        self._state = RobotState(s.joints_rad, status, s.joints_at_s, now)
                    self._lock.notify_all()
        except (OSError, sm.ProtocolError) as e:
            with self._lock:
                if not self._closed:
                    self._link_error = f"state stream lost: {e}"
                self._lock.notify_all()

    def close(self) -> None:
        with self._lock:
            self._closed = True
        for sock in (self._motion, getattr(self, "_state_socket", None)):
            if sock is not None:
                with contextlib.suppress(OSError):
                    sock.shutdown(socket.SHUT_RDWR)
                sock.close()

    # -- state ------------------------------------------------------------------------------

    def state(self) -> RobotState:
        """The newest state; RobotStoppedError when the stream failed or went silent."""
        with self._lock:
            state, error = self._state, self._link_error
        if error is not None:
            raise RobotStoppedError(f"robot link: {error}")
        silent_s = time.monotonic() - state.joints_at_s
        if silent_s > self.settings.state_timeout_s:
            raise RobotStoppedError(
                f"robot link: no joint state from {self._where(self.settings.state_port)} for "
                f"{silent_s:.2f} s (hardware.robot.state_timeout_s: "
                f"{self.settings.state_timeout_s})"
            )
        return state

    def joint_positions(self) -> np.ndarray:
        return self.state().joints_rad.copy()

    def refusal(self) -> str | None:
        """Why the controller cannot move now (from its STATUS), or None."""
        status = self.state().status
        return status.refusal() if status is not None else "no STATUS received"

    # -- motion -----------------------------------------------------------------------------

    def execute(self, trajectory: JointTrajectory) -> None:
        if not trajectory.joint_linear:
            raise ValueError(
                "the VAL 3 server runs straight joint-space moves between points: it needs a "
                "trajectory whose joint-linear path was checked (Planner.executable)"
            )
        refusal = self.refusal()
        if refusal is not None:
            raise RobotStoppedError(f"robot: not moving: {refusal}")
        points = np.asarray(trajectory.positions_rad, float)
        q_now = self.joint_positions()
        if np.abs(points[0] - q_now).max() > self.settings.path_tolerance_rad:
            raise RobotStoppedError(
                "robot: not moving: the trajectory starts "
                f"{np.abs(points[0] - q_now).max():.4f} rad from the measured joints"
            )
        try:
            sent = self._stream(points)
            self._wait_arrival(points, sent)
        except BaseException:
            # A failed link, and anything else that ends the motion early (Ctrl-C included),
            # stops the arm: queued points must not run on without a watcher.
            self.stop()
            raise

    def _stream(self, points: np.ndarray) -> int:
        """Send points 1.. in order (each resent while the queue is full), watching the arm;
        returns how many points were accepted (all of them)."""
        for k in range(1, len(points)):
            refused_at = time.monotonic()
            deadline = refused_at + self._drain_time_s(points)
            while not self._send_point(points[k]):
                state = self._watch(points, k - 1)
                # FAILURE means a full queue or a point the controller will never take (its
                # joint limits): once the arm rests on the last accepted point, with a STATUS
                # newer than the refusal, the queue is empty and the point itself is refused.
                idle = (
                    state.status_at_s > refused_at
                    and state.status.in_motion == 0
                    and np.abs(state.joints_rad - points[k - 1]).max() <= ARRIVAL_TOLERANCE_RAD
                )
                if idle or time.monotonic() > deadline:
                    why = "with its queue empty" if idle else "until its queue should have drained"
                    raise RobotStoppedError(
                        f"robot: the controller refused point {k} of {len(points) - 1} {why} "
                        "(outside its joint limits?); the arm was stopped"
                    )
                time.sleep(RESEND_PERIOD_S)
            self._watch(points, k)
        return len(points) - 1

    def _drain_time_s(self, points: np.ndarray) -> float:
        """Time for a full 10-deep queue of the longest chords to run, plus a margin."""
        chords = np.abs(np.diff(points, axis=0)).max(axis=0) if len(points) > 1 else 0
        speed = self.settings.speed_fraction * np.array(_nominal_speeds())
        longest_s = float(np.max(chords / speed)) if len(points) > 1 else 0.0
        return 10 * (longest_s + 0.5) + 1.0

    def _send_point(self, q: np.ndarray) -> bool:
        self._sequence += 1
        point = sm.JointTrajPt(self._sequence, q, self.settings.speed_fraction, 0.0)
        header, body = self._request(sm.encode_traj_pt(point))
        if header.reply_code not in (sm.SUCCESS, sm.FAILURE):
            raise RobotStoppedError(f"robot link: reply code {header.reply_code} to a point")
        return header.reply_code == sm.SUCCESS

    def _request(self, packet: bytes) -> tuple[sm.Header, bytes]:
        try:
            self._motion.settimeout(REPLY_TIMEOUT_S)
            self._motion.sendall(packet)
            header, body = sm.read_packet(self._motion, {sm.JOINT_TRAJ_PT})
        except (OSError, sm.ProtocolError) as e:
            raise RobotStoppedError(
                f"robot link: motion connection {self._where(self.settings.motion_port)} "
                f"failed ({e})"
            ) from None
        if header.comm_type != sm.SERVICE_REPLY:
            raise RobotStoppedError(
                f"robot link: expected a reply, got comm type {header.comm_type}"
            )
        return header, body

    def _watch(self, points: np.ndarray, sent: int) -> RobotState:
        """The arm must stay on the polyline through points[0..sent] and the controller fit."""
        state = self.state()
        if state.status is not None and state.status.refusal() is not None:
            raise RobotStoppedError(f"robot: {state.status.refusal()} during the motion")
        off = path_deviation_rad(state.joints_rad, points[: sent + 1])
        if off > self.settings.path_tolerance_rad:
            raise RobotStoppedError(
                f"robot: the measured joints left the commanded path by {off:.4f} rad "
                f"(hardware.robot.path_tolerance_rad: {self.settings.path_tolerance_rad})"
            )
        return state

    def _wait_arrival(self, points: np.ndarray, sent: int) -> None:
        """At rest at the last point: every joint within ARRIVAL_TOLERANCE_RAD of it and a
        STATUS sent after the last point was accepted saying not in motion."""
        accepted_at = time.monotonic()
        speed = self.settings.speed_fraction * np.array(_nominal_speeds())
        travel_s = float(np.sum(np.abs(np.diff(points, axis=0)).max(axis=0) / speed))
        deadline = accepted_at + 3 * travel_s + 0.3 * len(points) + 5.0
        while True:
            state = self._watch(points, sent)
            at_goal = np.abs(state.joints_rad - points[-1]).max() <= ARRIVAL_TOLERANCE_RAD
            if at_goal and state.status_at_s > accepted_at and state.status.in_motion == 0:
                return
            if time.monotonic() > deadline:
                raise RobotStoppedError(
                    "robot: the arm did not arrive at its goal in time; the arm was stopped"
                )
            with self._lock:
                self._lock.wait(0.05)

    def stop(self) -> None:
        """Stop now and clear the controller's queue (sequence -4); best effort, since the
        server also stops when a connection drops."""
        try:
            point = sm.JointTrajPt(sm.STOP_TRAJECTORY, np.zeros(6), 0.0, 0.0)
            self._request(sm.encode_traj_pt(point))
        except RobotStoppedError:
            pass


def path_deviation_rad(q: np.ndarray, path: np.ndarray) -> float:
    """Largest joint deviation of q from the nearest point of the joint-space polyline `path`
    (the nearest in the Euclidean sense, measured per joint as the limits are)."""
    if len(path) == 1:
        return float(np.abs(q - path[0]).max())
    a, d = path[:-1], np.diff(path, axis=0)
    length2 = np.einsum("ij,ij->i", d, d)
    s = np.clip(np.einsum("ij,ij->i", q - a, d) / np.where(length2 > 0, length2, 1.0), 0, 1)
    return float(np.abs(q - (a + s[:, None] * d)).max(axis=1).min())


def _nominal_speeds() -> tuple[float, ...]:
    from robots.models.rx60 import RX60

    return RX60().velocity_limits_rad_s


def connect_val3(settings: RobotLinkConfig) -> Val3Robot:
    """Connect both ports and wait for the first state (one-line ScannerError otherwise)."""
    return Val3Robot(settings)
