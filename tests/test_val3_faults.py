"""The VAL 3 driver against a controller that lies (tests/fake_val3.py): every fault stops the
motion with one line, nothing but the stop (sequence -4) is sent once the fault could be seen,
and the fault is seen within the state timeout. Covers NaN readings, replies out of step, a
stale STATUS, motion on stale state, the speed floor, and the faults that already held."""

from __future__ import annotations

import math
import struct
import time

import numpy as np
import pytest

from reconstruction.common.errors import ScannerError
from robots.drivers import simple_message as sm
from robots.drivers import staubli_val3
from robots.drivers.interfaces import JointTrajectory
from robots.drivers.settings import RobotLinkConfig
from robots.drivers.staubli_val3 import RobotStoppedError, Val3Robot
from tests.fake_val3 import FakeController, reply, reply_code

Q0 = np.array([0.0, -0.4, 2.3, 0.0, 0.8, 0.0])
STATE_TIMEOUT_S = 0.3
# STATUS comes every 0.1 s and the driver's waits look again every POLL_S: a stale STATUS is
# seen at most this long after the limit.
STATUS_SLACK_S = 0.1 + staubli_val3.POLL_S
STOP = sm.STOP_TRAJECTORY


@pytest.fixture
def fake():
    with FakeController(Q0) as controller:
        yield controller


@pytest.fixture
def robot(fake):
    driver = connect(fake)
    yield driver
    driver.close()


def connect(fake: FakeController, **fields) -> Val3Robot:
    motion, state = fake.ports
    settings = RobotLinkConfig(
        motion_port=motion,
        state_port=state,
        speed_fraction=0.5,
        state_timeout_s=STATE_TIMEOUT_S,
        # Generous: the wait ends at the first state; a loaded machine (a profiler pausing the
        # workers) once needed more than 2 s for it.
        connect_timeout_s=3.0,
        **fields,
    )
    return Val3Robot(settings)


def trajectory(n: int = 30, step_rad: float = 0.01) -> JointTrajectory:
    """n points 0.01 rad apart in every joint: the fake's arm takes 20 ms for each."""
    q = Q0 + np.arange(n)[:, None] * step_rad
    return JointTrajectory(np.linspace(0.0, 1.0, n), q, joint_linear=True)


def topic(packet: bytes) -> bytes:
    """The same reply sent as a TOPIC."""
    return sm.packet(sm.Header(sm.JOINT_TRAJ_PT, sm.TOPIC, sm.SUCCESS), packet[16:])


def stops_at_once(fake, robot, at, fault, match, closed=None, within_s=STATE_TIMEOUT_S):
    """Run the standard trajectory with the request `at` answered by `fault` (FakeController.
    fault_at; a sequence number is the k-th point while the queue takes every point): it must
    end in one line matching `match`, only the stop sent after the fault (once the driver
    closed motion connection `closed`, when given), the fault seen within `within_s`."""
    fake.fault_at(at, fault)
    with pytest.raises(RobotStoppedError, match=match) as error:
        robot.execute(trajectory())
    seen_s = time.monotonic()
    assert "\n" not in str(error.value)
    assert seen_s - fake.fault_at_s <= within_s
    assert fake.sent_after(fake.fault_at_s, closed=closed) == [STOP]


# --- 1. NaN and infinities -------------------------------------------------------------------


def test_nan_joints_from_the_start_refuse_the_connection_and_nothing_is_sent(fake):
    fake.joints_wire = [0.0, math.nan, 2.3, 0.0, 0.8, 0.0]
    with pytest.raises(ScannerError, match=r"did not stream .*joints\[1\]: nan is not a finite"):
        connect(fake)
    assert fake.requests == []


def test_a_nan_joint_before_a_motion_refuses_it_and_never_reaches_the_caller(fake, robot):
    fake.joints_wire = [math.inf, -0.4, 2.3, 0.0, 0.8, 0.0]
    time.sleep(0.1)
    with pytest.raises(RobotStoppedError, match=r"joints\[0\]: inf is not a finite"):
        robot.joint_positions()
    with pytest.raises(RobotStoppedError, match="state stream lost"):
        robot.execute(trajectory())
    assert fake.sent_after(0.0) in ([], [STOP])


def test_a_nan_joint_mid_motion_stops_the_arm_at_once(fake, robot):
    def nan_then_reply(request, normal):
        fake.joints_wire = [0.03, math.nan, 2.33, 0.03, 0.83, 0.03]
        return [(0.05, normal)]  # the NaN reading reaches the driver before this reply

    stops_at_once(fake, robot, 3, nan_then_reply, r"joints\[1\]: nan is not a finite number")
    with pytest.raises(RobotStoppedError):
        robot.joint_positions()


def test_a_nan_in_a_reply_is_a_protocol_error_naming_the_field(fake, robot):
    bad = bytearray(reply(4))
    bad[16 + 44 : 16 + 48] = struct.pack("<f", math.nan)  # the velocity field
    match = r"robot link: .*velocity: nan is not a finite number"
    stops_at_once(fake, robot, 4, lambda request, normal: [(0.0, bytes(bad))], match, closed=1)


def test_a_trajectory_with_a_nan_is_refused_before_anything_is_sent(fake, robot):
    q = trajectory().positions_rad.copy()
    q[5, 2] = math.nan
    with pytest.raises(ValueError, match="not finite"):
        robot.execute(JointTrajectory(np.linspace(0, 1, len(q)), q, joint_linear=True))
    assert fake.requests == []


def test_a_nan_deviation_fails_every_check_that_lets_the_arm_move():
    assert not staubli_val3.within(math.nan, 1.0)
    assert not staubli_val3.within(math.inf, 1.0)
    assert staubli_val3.within(0.5, 1.0)
    path = np.stack([Q0, Q0 + 0.1])
    q = Q0.copy()
    q[2] = math.nan
    assert math.isnan(staubli_val3.path_deviation_rad(q, path))


# --- 2. replies matched with their requests --------------------------------------------------


@pytest.mark.parametrize(
    "wrong, match",
    [
        (lambda seq: reply(seq - 1), r"answered point 5 with the reply to point 4"),
        (lambda seq: reply(seq + 7), r"answered point 5 with the reply to point 12"),
        (lambda seq: topic(reply(seq)), r"sent comm type 1 where point 5's reply was due"),
        (lambda seq: reply(seq, sm.INVALID), r"answered point 5 with reply code 0"),
    ],
    ids=["previous sequence", "other sequence", "a topic", "reply code invalid"],
)
def test_a_reply_out_of_step_stops_and_closes_the_motion_connection(fake, robot, wrong, match):
    def out_of_step(request, normal):
        return [(0.0, wrong(request.point.sequence))]

    stops_at_once(fake, robot, 5, out_of_step, "robot link: .*" + match, closed=1)


def test_a_duplicate_reply_stops_before_the_next_point(fake, robot):
    twice = lambda request, normal: [(0.0, normal + normal)]  # noqa: E731
    stops_at_once(fake, robot, 6, twice, "robot link: .* sent a reply to no request", closed=1)


def test_a_reply_to_nothing_while_the_arm_runs_on_stops_it(fake, robot):
    goal = trajectory().positions_rad[-1]

    def then_a_stray(request, normal):
        if reply_code(normal) != sm.SUCCESS:
            return None  # the queue was full: the point comes again
        # The arm, 20 ms a point with up to 10 queued, is still on its way 50 ms later.
        return [(0.0, normal), (0.05, reply(request.point.sequence))]

    last = lambda request: np.allclose(request.point.joints_rad, goal, atol=1e-6)  # noqa: E731
    match = "robot link: .* sent a reply to no request"
    stops_at_once(fake, robot, last, then_a_stray, match, closed=1)


def test_a_late_reply_closes_the_link_and_a_reused_driver_pairs_replies_right(fake, robot):
    late = lambda request, normal: [(STATE_TIMEOUT_S + 0.2, normal)]  # noqa: E731
    match = r"robot link: no reply to point 7 .* within 0.3 s"
    # Seen at the limit itself, the stop sent and the connection closed after it; the late
    # reply then goes out on a connection the driver has closed.
    stops_at_once(fake, robot, 7, late, match, closed=1, within_s=STATE_TIMEOUT_S + 0.1)
    # The next motion, on a new connection, is refused point by point: the driver must report
    # it, not read an old reply as the answer to a refused point.
    fake.answer = lambda request, normal: [(0.0, normal)]
    fake.refuse_all = True
    q = fake.q_rad + np.arange(3)[:, None] * 0.01
    second_s = time.monotonic()
    with pytest.raises(RobotStoppedError, match="refused point 1 of 2 with the arm at rest"):
        robot.execute(JointTrajectory(np.linspace(0, 1, 3), q, joint_linear=True))
    assert {r.connection for r in fake.requests if r.at_s > second_s} == {2}


# --- 3. STATUS has its own age limit ---------------------------------------------------------


def test_a_stale_status_stops_the_arm_though_joints_keep_coming(fake, robot):
    def status_stops(request, normal):
        fake.send_status = False
        return [(0.0, normal)]

    fake.fault_at(2, status_stops)
    with pytest.raises(RobotStoppedError, match=r"robot link: no STATUS from .* for 0\.3\d s"):
        robot.execute(trajectory())
    seen_s = time.monotonic()
    stopped_s = max(t for t in fake.status_sent_at)  # the last STATUS sent
    with fake._lock:
        requests = list(fake.requests)
    # No point went out on a STATUS older than the limit (20 ms: the send after the check).
    for request in requests:
        if request.point.sequence != STOP and request.at_s > stopped_s:
            assert request.at_s - stopped_s <= STATE_TIMEOUT_S + 0.02
    assert requests[-1].point.sequence == STOP
    assert seen_s - stopped_s <= STATE_TIMEOUT_S + STATUS_SLACK_S


# --- 6. motion only on fresh state, and a give-up message that does not guess -----------------


def test_no_motion_is_sent_on_state_that_stopped_coming_before_it_was_asked(fake, robot):
    fake.send_joints = fake.send_status = False
    fake.fault()
    time.sleep(0.15)  # younger than the state timeout, but older than the call
    with pytest.raises(RobotStoppedError, match="no joint state"):
        robot.execute(trajectory())
    assert fake.sent_after(fake.fault_at_s) in ([], [STOP])
    assert time.monotonic() - fake.fault_at_s <= STATE_TIMEOUT_S + STATUS_SLACK_S


def test_a_queue_held_too_long_is_given_up_without_guessing_why(fake, robot, monkeypatch):
    monkeypatch.setattr(staubli_val3, "POINT_SETTLE_S", 0.0)
    monkeypatch.setattr(staubli_val3, "DRAIN_MARGIN_S", 0.2)
    fake.hold = True
    match = r"refused point 11 of 29 for 0\.\d s, longer than its queue"
    with pytest.raises(RobotStoppedError, match=match) as error:
        robot.execute(trajectory())
    assert "joint limits" not in str(error.value)
    assert fake.sent_after(0.0)[-1] == STOP


# --- 5. the speed floor --------------------------------------------------------------------


@pytest.mark.parametrize("fraction", [1e-38, 0.001, 0.0, math.nan])
def test_a_speed_fraction_below_the_floor_is_refused(fraction):
    with pytest.raises(ScannerError, match=r"hardware.robot.speed_fraction: expected .*, got"):
        RobotLinkConfig(speed_fraction=fraction)
    if fraction > 0:
        with pytest.raises(ScannerError, match=r"speed_fraction: .* in \[0.01, 1\]"):
            RobotLinkConfig(speed_fraction=fraction)


def test_the_driver_refuses_a_speed_below_the_floor_however_its_settings_were_made(fake, robot):
    # A loader that fills the record without running its checks.
    object.__setattr__(robot.settings, "speed_fraction", 1e-38)
    with pytest.raises(ScannerError, match="speed_fraction"):
        robot.execute(trajectory())
    assert fake.requests == []


# --- faults that already held: still stopped at once, nothing more streamed ------------------


@pytest.mark.parametrize(
    "answer, match",
    [
        (struct.pack("<iiii", 2**31 - 1, 11, 3, 1), "length 2147483647"),
        (struct.pack("<iiii", -1, 11, 3, 1), "length -1"),
        (b"HTTP/1.1 400 Bad Request\r\n\r\n" + bytes(40), "expected a simple_message"),
    ],
    ids=["length 2^31-1", "length -1", "garbage"],
)
def test_a_reply_that_is_no_packet_stops_the_arm(fake, robot, answer, match):
    broken = lambda request, normal: [(0.0, answer)]  # noqa: E731
    stops_at_once(fake, robot, 4, broken, "robot link: .*" + match, closed=1)


def test_a_motion_connection_closed_mid_motion_stops_with_nothing_more_sent(fake, robot):
    def hang_up(request, normal):
        fake.fault()
        raise OSError("the fake hangs up")

    fake.fault_at(4, hang_up)
    with pytest.raises(RobotStoppedError, match="robot link: motion connection .* failed"):
        robot.execute(trajectory())
    assert time.monotonic() - fake.fault_at_s <= STATE_TIMEOUT_S
    assert fake.sent_after(fake.fault_at_s) == []


@pytest.mark.parametrize(
    "fault, match",
    [
        (lambda fake: setattr(fake, "status", sm.RobotStatus(0, 1, 0, 0, 0, 2, 0)), "emergency"),
        (lambda fake: setattr(fake, "offset_rad", np.full(6, 0.05)), "left the commanded path"),
        (lambda fake: setattr(fake, "state_inject", bytes(60)), "state stream lost: expected"),
        (lambda fake: setattr(fake, "state_hang_up", True), "state stream lost: the connection"),
    ],
    ids=["e-stop", "path deviation", "state garbage", "state connection closed"],
)
def test_a_bad_state_mid_motion_stops_the_arm_and_only_the_stop_follows(fake, robot, fault, match):
    def apply(request, normal):
        fault(fake)
        # Answered once the next state message has gone out (STATUS: within 0.1 s).
        return [(0.12, normal)]

    stops_at_once(fake, robot, 3, apply, match)


def test_a_full_queue_is_waited_out_and_every_point_runs_once(fake, robot):
    robot.execute(trajectory())
    points = fake.points()
    assert len(points) > 29  # the 10-deep queue refused some, which were sent again
    assert len({p.sequence for p in points}) == len(points)
    assert np.abs(robot.joint_positions() - trajectory().positions_rad[-1]).max() < 1e-6
    assert STOP not in fake.sent_after(0.0)
