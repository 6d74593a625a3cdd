"""The RX60's controller link: the simple_message bytes against the protocol's own layout, and
the VAL 3 driver against the controller emulator over loopback TCP: motions, refusals, and every
fault ending as specified (stopped, one line, the arm never moving on a bad link)."""

from __future__ import annotations

import math
import socket
import struct
import threading
import time
from dataclasses import replace

import numpy as np
import pytest

from reconstruction.common.errors import ScannerError
from robots.drivers import simple_message as sm
from robots.drivers.interfaces import JointTrajectory
from robots.drivers.settings import RobotLinkConfig
from robots.drivers.staubli_val3 import RobotStoppedError, Val3Robot, path_deviation_rad
from robots.emulator.val3_server import EmulatorSettings, Val3Emulator
from robots.simulation.cell import HOME_Q

# The protocol's example: JOINT_TRAJ_PT, sequence 1, velocity 0.1, duration 5.0, and its reply.
EXAMPLE_REQUEST = bytes.fromhex(
    "400000000b000000020000000000000001000000000060a7e8cda73e579e5dbfdb0f49c05f81343f"
    "db0f49c000000000000000000000000000000000cdcccc3d0000a040"
)
EXAMPLE_REPLY = bytes.fromhex("400000000b000000030000000100000001000000") + bytes(48)
# Emulated seconds per wall second: moves of a second take 50 ms, the streams keep real rates.
FAST = 20.0


def test_the_protocol_example_decodes_as_the_val3_server_reads_it_and_encodes_back():
    # decTrajPt.pgx reads the body at fixed offsets: sequence at 0 ("-4l": int32 LE), joint i
    # at 4 + 4 i, velocity at 44, duration at 48 ("4.0l": float32 LE); the prefix length is
    # 64 (setupRosMsgs.pgx: 12 + 52) and the header is type 11, comm type 2 (request).
    prefix, msg_type, comm, reply = struct.unpack_from("<4i", EXAMPLE_REQUEST)
    assert (prefix, msg_type, comm, reply) == (64, 11, 2, 0) and len(EXAMPLE_REQUEST) == 4 + 64
    body = EXAMPLE_REQUEST[16:]
    assert struct.unpack_from("<i", body, 0)[0] == 1
    joints = [struct.unpack_from("<f", body, 4 + 4 * i)[0] for i in range(10)]
    expected = [0.0, 0.3277, -0.8657, -math.pi, 0.7051, -math.pi, 0, 0, 0, 0]
    assert joints == pytest.approx(expected, abs=1e-4)
    assert struct.unpack_from("<f", body, 44)[0] == pytest.approx(0.1)
    assert struct.unpack_from("<f", body, 48)[0] == 5.0
    point = sm.decode_traj_pt(body)
    assert point.sequence == 1 and point.velocity == pytest.approx(0.1)
    # The codec writes the same bytes for the same values (the 6 joints of the RX60 and four
    # zero slots).
    again = sm.JointTrajPt(1, np.array(joints[:6]), point.velocity, point.duration_s)
    assert sm.encode_traj_pt(again) == EXAMPLE_REQUEST
    # encTrajPtAck.pgx: prefix 64, type 11, comm 3 (reply), reply code 1, the sequence echoed,
    # everything else zero.
    assert sm.encode_traj_pt_reply(1, sm.SUCCESS) == EXAMPLE_REPLY


def test_state_messages_have_the_servers_lengths():
    # setupRosMsgs.pgx: JOINT_POSITION prefix 56, STATUS prefix 40, both topics (comm type 1).
    joint = sm.encode_joint_position(np.arange(6) * 0.1)
    status = sm.encode_status(sm.RobotStatus(1, 0, 0, 0, 1, 2, 1))
    assert struct.unpack_from("<4i", joint) == (56, 10, 1, 0) and len(joint) == 60
    assert struct.unpack_from("<4i", status) == (40, 13, 1, 0) and len(status) == 44
    assert sm.decode_status(status[16:]) == sm.RobotStatus(1, 0, 0, 0, 1, 2, 1)


def test_path_deviation_is_measured_to_the_nearest_chord():
    path = np.array([[0.0] * 6, [1.0] + [0.0] * 5, [1.0, 1.0] + [0.0] * 4])
    assert path_deviation_rad(np.array([0.5, 0, 0, 0, 0, 0]), path) == 0.0
    assert path_deviation_rad(np.array([1.0, 0.5, 0.01, 0, 0, 0]), path) == pytest.approx(0.01)
    assert path_deviation_rad(np.array([0.5, 0.3, 0, 0, 0, 0]), path) == pytest.approx(0.3)


# --- the driver against the emulator ---------------------------------------------------------


@pytest.fixture
def emulator():
    settings = replace(
        EmulatorSettings(), motion_port=0, state_port=0, connect_delay_s=0.05, time_scale=FAST
    )
    with Val3Emulator(settings, HOME_Q).start() as em:
        yield em


def link(em: Val3Emulator, **fields) -> RobotLinkConfig:
    return RobotLinkConfig(
        host="127.0.0.1",
        motion_port=em.motion_address[1],
        state_port=em.state_address[1],
        speed_fraction=0.5,
        **fields,
    )


def straight(q_a, q_b, n: int = 8) -> JointTrajectory:
    s = np.linspace(0.0, 1.0, n)[:, None]
    return JointTrajectory(np.linspace(0, 1, n), q_a + s * (q_b - q_a), joint_linear=True)


def watch(robot: Val3Robot, seconds: float) -> list[np.ndarray]:
    """Joints the driver reports during `seconds`, sampled from another thread."""
    seen, end = [], time.monotonic() + seconds
    while time.monotonic() < end:
        try:
            seen.append(robot.state().joints_rad.copy())
        except RobotStoppedError:
            break
        time.sleep(0.005)
    return seen


def test_a_move_streams_the_checked_points_and_ends_at_rest_on_the_goal(emulator):
    robot = Val3Robot(link(emulator))
    try:
        q0 = robot.joint_positions()
        assert np.abs(q0 - HOME_Q).max() < 1e-6  # float32 on the wire
        goal = q0 + np.array([0.3, -0.2, -0.1, 0.4, 0.2, -0.3])
        trajectory = straight(q0, goal)
        seen = []
        watcher = threading.Thread(target=lambda: seen.extend(watch(robot, 1.0)))
        watcher.start()
        robot.execute(trajectory)
        watcher.join()
        assert np.abs(robot.joint_positions() - goal).max() < 1e-5
        assert robot.state().status.in_motion == 0
        # Exactly the trajectory's points, in order, at the configured speed fraction.
        sent = [p for p in emulator.received if p.sequence >= 0]
        assert len(sent) == len(trajectory.positions_rad) - 1
        for point, q in zip(sent, trajectory.positions_rad[1:]):
            assert np.abs(point.joints_rad - q).max() < 1e-6
            assert point.velocity == pytest.approx(0.5)
        # The arm the wire reported stayed on the straight joint-space path.
        assert len(seen) > 5
        assert max(path_deviation_rad(q, trajectory.positions_rad) for q in seen) < 1e-5
    finally:
        robot.close()


def test_a_trajectory_not_checked_as_joint_linear_is_never_sent(emulator):
    robot = Val3Robot(link(emulator))
    try:
        q0 = robot.joint_positions()
        sampled = JointTrajectory(np.array([0.0, 1.0]), np.stack([q0, q0 + 0.1]))
        with pytest.raises(ValueError, match="joint-linear"):
            robot.execute(sampled)
        assert emulator.received == []
    finally:
        robot.close()


def test_an_emergency_stop_refuses_motion_before_anything_is_sent(emulator):
    robot = Val3Robot(link(emulator))
    try:
        emulator.e_stop()
        time.sleep(0.25)  # STATUS comes at 10 Hz
        q0 = robot.joint_positions()
        with pytest.raises(RobotStoppedError, match="not moving: .*emergency stop"):
            robot.execute(straight(q0, q0 + 0.2))
        assert [p for p in emulator.received if p.sequence >= 0] == []
        assert np.abs(emulator.joint_positions() - q0).max() < 1e-6
    finally:
        robot.close()


def _interrupted(emulator, fault, match: str, **fields) -> Val3Robot:
    """Start a long move, apply `fault` mid-way, and check the driver stops with `match`."""
    robot = Val3Robot(link(emulator, **fields))
    q0 = robot.joint_positions()
    goal = q0 + np.array([1.2, -0.6, -0.5, 1.5, 0.6, -1.5])
    timer = threading.Timer(0.15, fault)
    timer.start()
    try:
        with pytest.raises(RobotStoppedError, match=match):
            robot.execute(straight(q0, goal, 30))
    finally:
        timer.cancel()
    return robot


def test_an_emergency_stop_during_a_move_stops_the_arm_and_the_scan(emulator):
    robot = _interrupted(emulator, emulator.e_stop, "emergency stop during the motion")
    held = emulator.joint_positions()
    time.sleep(0.2)
    assert np.abs(emulator.joint_positions() - held).max() == 0.0
    assert emulator.status().e_stopped == 1
    robot.close()


def test_a_silent_state_stream_stops_the_arm_within_the_timeout(emulator):
    started = {}

    def stall():
        started["at"] = time.monotonic()
        emulator.stall_state(None)

    robot = _interrupted(emulator, stall, "(no joint state|no STATUS|state).*0.5")
    stopped_after = time.monotonic() - started["at"]
    assert 0.45 <= stopped_after < 1.5  # the last message came up to 20 ms before the stall
    # The driver sent the stop (sequence -4) and the arm stands still.
    assert any(p.sequence == sm.STOP_TRAJECTORY for p in emulator.received)
    held = emulator.joint_positions()
    time.sleep(0.2)
    assert np.abs(emulator.joint_positions() - held).max() == 0.0
    emulator.resume_state()
    robot.close()


def test_a_dropped_connection_stops_the_scan(emulator):
    robot = _interrupted(emulator, emulator.drop_connections, "robot link")
    held = emulator.joint_positions()
    time.sleep(0.2)
    assert np.abs(emulator.joint_positions() - held).max() == 0.0  # resetMotion on the server
    robot.close()


def test_joints_leaving_the_commanded_path_stop_the_arm(emulator):
    offset = np.array([0.0, 0.05, 0.0, 0.0, 0.0, 0.0])
    robot = _interrupted(
        emulator,
        lambda: emulator.set_reported_offset(offset),
        r"left the commanded path by 0\.0[2-5]\d* rad .*path_tolerance_rad: 0.02",
    )
    assert any(p.sequence == sm.STOP_TRAJECTORY for p in emulator.received)
    robot.close()


def test_a_full_queue_is_waited_out_and_the_move_completes(emulator):
    robot = Val3Robot(link(emulator))
    try:
        q0 = robot.joint_positions()
        goal = q0 + np.array([0.3, 0.3, -0.3, 0.3, 0.3, 0.3])
        emulator.hold_queue(True)
        threading.Timer(0.4, lambda: emulator.hold_queue(False)).start()
        robot.execute(straight(q0, goal, 20))  # 19 points: more than the 10-deep queue
        assert np.abs(robot.joint_positions() - goal).max() < 1e-5
        sent = [p for p in emulator.received if p.sequence >= 0]
        assert len(sent) > 19  # some were refused (queue full) and sent again
        accepted = {p.sequence for p in sent}
        assert len(accepted) == len(sent)  # every resend is a new sequence number
    finally:
        robot.close()


def test_a_point_the_controller_refuses_stops_the_move_with_a_reason():
    # The controller's software limits narrower than the model's: J1 beyond 0.1 rad refused.
    lower = np.array(EmulatorSettings().lower_limits_rad)
    upper = np.array(EmulatorSettings().upper_limits_rad)
    upper[0] = 0.1
    settings = replace(
        EmulatorSettings(),
        motion_port=0,
        state_port=0,
        connect_delay_s=0.05,
        time_scale=FAST,
        lower_limits_rad=tuple(lower),
        upper_limits_rad=tuple(upper),
    )
    with Val3Emulator(settings, HOME_Q).start() as em:
        robot = Val3Robot(link(em))
        try:
            q0 = robot.joint_positions()
            with pytest.raises(RobotStoppedError, match="refused point"):
                robot.execute(straight(q0, q0 + np.array([0.3, 0, 0, 0, 0, 0]), 7))
            assert em.joint_positions()[0] <= 0.1 + 1e-6
        finally:
            robot.close()


def test_packets_split_into_many_segments_are_read_whole(emulator):
    emulator.set_split_writes(True)
    robot = Val3Robot(link(emulator))
    try:
        q0 = robot.joint_positions()
        goal = q0 + np.array([0.1, 0.1, -0.1, 0.1, 0.1, 0.1])
        robot.execute(straight(q0, goal, 4))
        assert np.abs(robot.joint_positions() - goal).max() < 1e-5
    finally:
        robot.close()


# --- bad links: one line naming the item, and nothing moves ---------------------------------


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_an_unreachable_controller_is_one_line_naming_the_port():
    port = _free_port()
    settings = RobotLinkConfig(motion_port=port, state_port=_free_port(), connect_timeout_s=0.5)
    with pytest.raises(
        ScannerError, match=f"hardware.robot.motion_port: cannot connect to 127.0.0.1:{port}"
    ):
        Val3Robot(settings)


def test_a_server_speaking_another_protocol_is_refused():
    """An HTTP server on the state port: its first bytes are no simple_message."""
    server = socket.create_server(("127.0.0.1", 0))
    accepted = []

    def serve():
        for _ in range(2):
            conn, _ = server.accept()
            accepted.append(conn)
            conn.sendall(b"HTTP/1.1 400 Bad Request\r\nContent-Length: 0\r\n\r\n")

    threading.Thread(target=serve, daemon=True).start()
    port = server.getsockname()[1]
    try:
        with pytest.raises(ScannerError, match="hardware.robot.state_port: .* did not stream"):
            Val3Robot(RobotLinkConfig(motion_port=port, state_port=port, connect_timeout_s=0.5))
    finally:
        for conn in accepted:
            conn.close()
        server.close()


# --- the emulator as users run it -------------------------------------------------------------


def test_emulate_controller_serves_until_stopped_and_refuses_a_busy_port():
    import re
    import subprocess
    import sys

    command = [sys.executable, "-m", "scanner", "emulate-controller"]
    ports = ["--motion-port", "0", "--state-port", "0"]
    process = subprocess.Popen(command + ports, stdout=subprocess.PIPE, text=True)
    try:
        first = process.stdout.readline()
        found = re.search(r"on 127\.0\.0\.1: motion port (\d+), state port (\d+)", first)
        assert found, first
        motion, state = int(found[1]), int(found[2])
        robot = Val3Robot(RobotLinkConfig(motion_port=motion, state_port=state))
        try:
            assert np.abs(robot.joint_positions() - HOME_Q).max() < 1e-6
            assert robot.refusal() is None
        finally:
            robot.close()
        # A port already taken (the running emulator's) is one line, exit 2.
        busy = subprocess.run(
            command + ["--motion-port", str(motion), "--state-port", "0"],
            capture_output=True,
            text=True,
            timeout=60,
        )
        assert busy.returncode == 2
        assert busy.stderr.startswith("scanner: error: --motion-port/--state-port: cannot listen")
        assert len(busy.stderr.strip().splitlines()) == 1
    finally:
        process.terminate()
        process.wait(timeout=10)


def test_an_interrupt_during_a_move_stops_the_arm(emulator, monkeypatch):
    """Ctrl-C while points are streamed: the driver sends the stop before it lets go."""
    robot = Val3Robot(link(emulator))
    try:
        q0 = robot.joint_positions()
        goal = q0 + np.array([1.2, -0.6, -0.5, 1.5, 0.6, -1.5])
        calls = {"n": 0}
        send = robot._send_point

        def interrupted(q):
            calls["n"] += 1
            if calls["n"] == 5:
                raise KeyboardInterrupt
            return send(q)

        monkeypatch.setattr(robot, "_send_point", interrupted)
        with pytest.raises(KeyboardInterrupt):
            robot.execute(straight(q0, goal, 30))
        assert emulator.received[-1].sequence == sm.STOP_TRAJECTORY
        held = emulator.joint_positions()
        time.sleep(0.2)
        assert np.abs(emulator.joint_positions() - held).max() == 0.0
    finally:
        robot.close()
