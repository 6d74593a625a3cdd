"""The RX60 through its controller: a client of the ROS-Industrial VAL 3 server (CS8/CS9).

The server (ros-industrial/staubli_val3_driver) listens on two TCP ports: motion (11000), where it
reads JOINT_TRAJ_PT service requests and answers each, and state (11002), where it streams
JOINT_POSITION every 20 ms and STATUS every 100 ms. It moves only while both are connected; it
runs each point as a `movej` (straight in joint space, blending off: the arm stops at every
point) at the point's speed fraction, from a 10-deep queue (FAILURE when full: resend later).

So the driver takes only trajectories whose joint-linear path was checked
(`JointTrajectory.joint_linear`, see planners/joint_linear.py) and streams exactly their
positions, at a speed fraction no lower than settings.MIN_SPEED_FRACTION. It moves only on what
it has verified: every number on the wire finite (simple_message refuses NaN and infinities), every
reply the reply to the request just sent (motion_link.py: anything else stops the arm and closes
the motion connection), the joints and STATUS each younger than state_timeout_s, and a motion
starts only on joints and a STATUS that arrived after it was asked for. It refuses to move while
STATUS says e-stopped, drives off, in error or motion not possible; it stops the arm (sequence
-4) and raises RobotStoppedError when the joints or STATUS grow older than state_timeout_s, a
connection drops, a reply is out of step or late, STATUS turns bad, or the measured joints leave
the commanded path by more than path_tolerance_rad. Every comparison that lets the arm move is
written with `within`, which a NaN fails. The scan then ends as interrupted (resumable) with
every capture kept.
"""

from __future__ import annotations

import socket
import threading
import time
from dataclasses import dataclass

import numpy as np

from reconstruction.common.errors import ScannerError
from robots.drivers import simple_message as sm
from robots.drivers.interfaces import JointTrajectory, RobotDriver
from robots.drivers.motion_link import MotionLink, MotionLinkError
from robots.drivers.settings import RobotLinkConfig, require_speed_fraction

# industrial_robot_client's streamer: a point is reached when every joint is within this of it.
ARRIVAL_TOLERANCE_RAD = 0.005
# A refused point is resent this often while the queue drains (FAILURE: queue full).
RESEND_PERIOD_S = 0.02
# How often a wait looks at the state again when no new message woke it.
POLL_S = 0.05
# A full queue drains in QUEUE_DEPTH moves (pushMotion.pgx: 10 deep), each its travel time
# plus POINT_SETTLE_S (blend off: each movej accelerates from rest and stops; the RX60 needs
# 0.3 s to reach nominal speed), plus DRAIN_MARGIN_S; a point refused for longer is given up.
QUEUE_DEPTH = 10
POINT_SETTLE_S = 0.5
DRAIN_MARGIN_S = 1.0


def within(value: float, limit: float) -> bool:
    """value <= limit, and false when value is NaN: the form of every check letting the arm move
    (a check written `value > limit` to stop it would let a NaN through)."""
    return bool(value <= limit)


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
        # A reply later than the state timeout is treated as the link going silent: while the
        # driver waits for it, nobody watches the arm.
        self._motion = MotionLink(
            lambda: self._connect(settings.motion_port, "motion_port"),
            settings.state_timeout_s,
            self._where(settings.motion_port),
        )
        self._motion.open()
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
        """Only reads: the server takes any byte on the state port as a heartbeat. A message
        the codec refuses (a NaN joint included) ends the stream for good."""
        self._state_socket.settimeout(None)
        try:
            while True:
                header, body = sm.read_packet(self._state_socket, {sm.JOINT_POSITION, sm.STATUS})
                if header.msg_type == sm.JOINT_POSITION:
                    q, status = sm.decode_joint_position(body), None
                else:
                    q, status = None, sm.decode_status(body)
                now = time.monotonic()
                with self._lock:
                    s = self._state
                    if q is not None:
                        self._state = RobotState(q, s.status, now, s.status_at_s)
                    else:
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
        self._motion.close()
        state_socket = getattr(self, "_state_socket", None)
        if state_socket is not None:
            sm.close_socket(state_socket)

    # -- state ------------------------------------------------------------------------------

    def state(self) -> RobotState:
        """The newest state; RobotStoppedError when the stream failed or when the joints or
        the STATUS are older than state_timeout_s (each has its own age)."""
        with self._lock:
            state, error = self._state, self._link_error
        if error is not None:
            raise RobotStoppedError(f"robot link: {error}")
        now = time.monotonic()
        for what, at_s in (("joint state", state.joints_at_s), ("STATUS", state.status_at_s)):
            silent_s = now - at_s
            if not within(silent_s, self.settings.state_timeout_s):
                raise RobotStoppedError(
                    f"robot link: no {what} from {self._where(self.settings.state_port)} for "
                    f"{silent_s:.2f} s (hardware.robot.state_timeout_s: "
                    f"{self.settings.state_timeout_s})"
                )
        return state

    def joint_positions(self) -> np.ndarray:
        return self.state().joints_rad.copy()

    def refusal(self) -> str | None:
        """Why the controller cannot move now (from its STATUS), or None."""
        return self.state().status.refusal()

    def _fresh_state(self, since_s: float) -> RobotState:
        """The first state whose joints and STATUS both arrived after `since_s`: a motion starts
        on what the controller says now, not on what it said up to state_timeout_s ago (the
        wait ends with state()'s error when either goes stale)."""
        while True:
            state = self.state()
            if state.joints_at_s > since_s and state.status_at_s > since_s:
                return state
            with self._lock:
                self._lock.wait(POLL_S)

    # -- motion -----------------------------------------------------------------------------

    def execute(self, trajectory: JointTrajectory) -> None:
        asked_at = time.monotonic()
        if not trajectory.joint_linear:
            raise ValueError(
                "the VAL 3 server runs straight joint-space moves between points: it needs a "
                "trajectory whose joint-linear path was checked (Planner.executable)"
            )
        points = np.asarray(trajectory.positions_rad, float)
        if not np.isfinite(points).all():
            raise ValueError("the trajectory holds joint positions that are not finite")
        require_speed_fraction(self.settings.speed_fraction)
        state = self._fresh_state(asked_at)
        refusal = state.status.refusal()
        if refusal is not None:
            raise RobotStoppedError(f"robot: not moving: {refusal}")
        start_off = float(np.abs(points[0] - state.joints_rad).max())
        if not within(start_off, self.settings.path_tolerance_rad):
            raise RobotStoppedError(
                f"robot: not moving: the trajectory starts {start_off:.4f} rad from the "
                "measured joints"
            )
        try:
            self._stream(points)
            self._wait_arrival(points)
        except BaseException:
            # A failed link, and anything else that ends the motion early (Ctrl-C included),
            # stops the arm: queued points must not run on without a watcher.
            self.stop()
            raise

    def _stream(self, points: np.ndarray) -> None:
        """Send points 1.. in order (each resent while the queue is full), watching the arm
        before every send, so no point goes out on state older than state_timeout_s."""
        last = len(points) - 1
        for k in range(1, len(points)):
            refused_at = time.monotonic()
            deadline = refused_at + self._drain_time_s(points)
            while True:
                self._watch(points, k - 1)
                if self._send_point(points[k]):
                    break
                state = self._watch(points, k - 1)
                # FAILURE means a full queue or a point the controller will never take (its
                # joint limits): once the arm rests on the last accepted point, with a STATUS
                # newer than the refusal, the queue is empty and the point itself is refused.
                at_rest = within(
                    float(np.abs(state.joints_rad - points[k - 1]).max()), ARRIVAL_TOLERANCE_RAD
                )
                if at_rest and state.status_at_s > refused_at and state.status.in_motion == 0:
                    raise RobotStoppedError(
                        f"robot: the controller refused point {k} of {last} with the arm at "
                        "rest and its queue empty (outside its joint limits?); the arm was "
                        "stopped"
                    )
                if time.monotonic() > deadline:
                    raise RobotStoppedError(
                        f"robot: the controller refused point {k} of {last} for "
                        f"{time.monotonic() - refused_at:.1f} s, longer than its queue takes to "
                        "drain; the arm was stopped"
                    )
                time.sleep(RESEND_PERIOD_S)

    def _drain_time_s(self, points: np.ndarray) -> float:
        """Time for a full queue of the longest chords to run, plus a margin."""
        chords = np.abs(np.diff(points, axis=0)).max(axis=0)
        speed = self.settings.speed_fraction * np.array(_nominal_speeds())
        longest_s = float(np.max(chords / speed))
        return QUEUE_DEPTH * (longest_s + POINT_SETTLE_S) + DRAIN_MARGIN_S

    def _send_point(self, q: np.ndarray) -> bool:
        # Sequence numbers stay positive int32s (negative ones are the protocol's commands).
        self._sequence = self._sequence % sm.INT32_MAX + 1
        point = sm.JointTrajPt(self._sequence, q, self.settings.speed_fraction, 0.0)
        try:
            return self._motion.request(point) == sm.SUCCESS
        except MotionLinkError as e:
            raise RobotStoppedError(f"robot link: {e}") from None

    def _watch(self, points: np.ndarray, sent: int) -> RobotState:
        """The arm must stay on the polyline through points[0..sent], the controller fit, and
        the motion port quiet between replies."""
        state = self.state()
        refusal = state.status.refusal()
        if refusal is not None:
            raise RobotStoppedError(f"robot: {refusal} during the motion")
        off = path_deviation_rad(state.joints_rad, points[: sent + 1])
        if not within(off, self.settings.path_tolerance_rad):
            raise RobotStoppedError(
                f"robot: the measured joints left the commanded path by {off:.4f} rad "
                f"(hardware.robot.path_tolerance_rad: {self.settings.path_tolerance_rad})"
            )
        try:
            self._motion.check_quiet()
        except MotionLinkError as e:
            raise RobotStoppedError(f"robot link: {e}") from None
        return state

    def _wait_arrival(self, points: np.ndarray) -> None:
        """At rest at the last point: every joint within ARRIVAL_TOLERANCE_RAD of it and a
        STATUS sent after the last point was accepted saying not in motion."""
        accepted_at = time.monotonic()
        speed = self.settings.speed_fraction * np.array(_nominal_speeds())
        travel_s = float(np.sum(np.abs(np.diff(points, axis=0)).max(axis=0) / speed))
        deadline = accepted_at + 3 * travel_s + 0.3 * len(points) + 5.0
        while True:
            state = self._watch(points, len(points) - 1)
            off = float(np.abs(state.joints_rad - points[-1]).max())
            at_goal = within(off, ARRIVAL_TOLERANCE_RAD)
            if at_goal and state.status_at_s > accepted_at and state.status.in_motion == 0:
                return
            if time.monotonic() > deadline:
                raise RobotStoppedError(
                    "robot: the arm did not arrive at its goal in time; the arm was stopped"
                )
            with self._lock:
                self._lock.wait(POLL_S)

    def stop(self) -> None:
        """Stop now and clear the controller's queue (sequence -4); best effort, since the
        server also stops when a connection drops."""
        self._motion.stop()


def path_deviation_rad(q: np.ndarray, path: np.ndarray) -> float:
    """Largest joint deviation of q from the nearest point of the joint-space polyline `path`
    (the nearest in the Euclidean sense, measured per joint as the limits are); NaN when q
    holds a NaN (numpy's max and min propagate it), which `within` then refuses."""
    if len(path) == 1:
        return float(np.abs(q - path[0]).max())
    a, d = path[:-1], np.diff(path, axis=0)
    length2 = np.einsum("ij,ij->i", d, d)
    s = np.clip(np.einsum("ij,ij->i", q - a, d) / np.where(length2 > 0, length2, 1.0), 0, 1)
    return float(np.abs(q - (a + s[:, None] * d)).max(axis=1).min())


def _nominal_speeds() -> tuple[float, ...]:
    from robots.arms.rx60 import RX60

    return RX60().velocity_limits_rad_s


def connect_val3(settings: RobotLinkConfig) -> Val3Robot:
    """Connect both ports and wait for the first state (one-line ScannerError otherwise)."""
    return Val3Robot(settings)
