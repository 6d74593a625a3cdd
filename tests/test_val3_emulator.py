"""The VAL 3 server emulator, spoken to with raw sockets and the simple_message codec."""

from __future__ import annotations

import socket
import struct
import time
from collections.abc import Iterator

import numpy as np
import pytest

from robots.arms.rx60 import ACCELERATION_TIME_S, RX60
from robots.drivers import simple_message as sm
from robots.emulator.arm import Arm, MoveJ
from robots.emulator.val3_server import EmulatorSettings, Val3Emulator

SETTINGS = EmulatorSettings(motion_port=0, state_port=0, connect_delay_s=0.05, time_scale=20.0)
Q0 = np.zeros(6)
# A long move: at 2 % speed about 7 s emulated, 0.35 s wall at time_scale 20.
GOAL = np.array([0.5, -0.4, 0.6, 1.0, -0.5, 1.5])
READ_TIMEOUT_S = 2.0


@pytest.fixture
def emu() -> Iterator[Val3Emulator]:
    with Val3Emulator(SETTINGS, Q0) as emulator:
        yield emulator


def connect(address: tuple[str, int], receive_buffer_bytes: int = 0) -> socket.socket:
    """A client; receive_buffer_bytes > 0 sets its SO_RCVBUF (for a client that never reads)."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    if receive_buffer_bytes > 0:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, receive_buffer_bytes)
    sock.settimeout(READ_TIMEOUT_S)
    sock.connect(address)
    return sock


def point(seq: int, q: np.ndarray, velocity: float = 0.5) -> bytes:
    return sm.encode_traj_pt(sm.JointTrajPt(seq, np.asarray(q, float), velocity))


def request(sock: socket.socket, packet: bytes) -> tuple[int, int]:
    """Send a point, return (sequence, reply_code) of the reply."""
    sock.sendall(packet)
    header, body = sm.read_packet(sock, {sm.JOINT_TRAJ_PT})
    assert header.comm_type == sm.SERVICE_REPLY
    return sm.decode_traj_pt(body).sequence, header.reply_code


def nothing_arrives(sock: socket.socket, seconds: float) -> bool:
    sock.settimeout(seconds)
    try:
        sock.recv(1)
        return False
    except TimeoutError:
        return True
    finally:
        sock.settimeout(READ_TIMEOUT_S)


class StateReader:
    """The state port's messages, with their arrival times."""

    def __init__(self, emu: Val3Emulator) -> None:
        self.sock = connect(emu.state_address)
        self.connected_s = time.monotonic()

    def next(self) -> tuple[float, int, bytes]:
        header, body = sm.read_packet(self.sock, {sm.JOINT_POSITION, sm.STATUS})
        return time.monotonic(), header.msg_type, body

    def joints(self) -> np.ndarray:
        while True:
            _, msg_type, body = self.next()
            if msg_type == sm.JOINT_POSITION:
                return sm.decode_joint_position(body)

    def wait_status(self, expected: sm.RobotStatus) -> None:
        """Read until a STATUS equal to `expected` (older ones may still be buffered)."""
        deadline = time.monotonic() + READ_TIMEOUT_S
        while time.monotonic() < deadline:
            _, msg_type, body = self.next()
            if msg_type == sm.STATUS and sm.decode_status(body) == expected:
                return
        raise AssertionError(f"no STATUS {expected}")

    def wait_joints(self, expected_rad: np.ndarray) -> None:
        deadline = time.monotonic() + READ_TIMEOUT_S
        while time.monotonic() < deadline:
            if np.allclose(self.joints(), expected_rad, atol=1e-6):
                return
        raise AssertionError(f"no JOINT_POSITION {expected_rad}")

    def drain(self) -> None:
        """Discard what has arrived (whole packets: call it between the server's writes)."""
        self.sock.setblocking(False)
        try:
            while self.sock.recv(4096):
                pass
        except BlockingIOError:
            pass
        finally:
            self.sock.settimeout(READ_TIMEOUT_S)


def connected(emu: Val3Emulator) -> tuple[socket.socket, StateReader]:
    """Both ports connected and streaming (motion runs only when both are up)."""
    state = StateReader(emu)
    motion = connect(emu.motion_address)
    state.joints()
    return motion, state


def wait_moving(emu: Val3Emulator, q_from: np.ndarray) -> None:
    deadline = time.monotonic() + READ_TIMEOUT_S
    while np.allclose(emu.joint_positions(), q_from, atol=1e-4):
        assert time.monotonic() < deadline, "the arm never started moving"
        time.sleep(0.005)


def assert_still(emu: Val3Emulator, seconds: float = 0.2) -> np.ndarray:
    q = emu.joint_positions()
    time.sleep(seconds)
    np.testing.assert_array_equal(emu.joint_positions(), q)
    return q


def test_reply_bytes(emu: Val3Emulator) -> None:
    motion, _ = connected(emu)
    motion.sendall(point(1, GOAL * 0.1))
    reply = sm.recv_exact(motion, 68)
    expected = bytes.fromhex("400000000b000000030000000100000001000000") + bytes(48)
    assert reply == expected
    assert emu.received[0].sequence == 1


def test_state_stream_timing(emu: Val3Emulator) -> None:
    state = StateReader(emu)
    messages = [state.next() for _ in range(32)]
    first_s = messages[0][0] - state.connected_s
    assert first_s >= SETTINGS.connect_delay_s  # recvHeartbeat.pgx: delay() before streaming
    joint_times = [t for t, kind, _ in messages if kind == sm.JOINT_POSITION]
    assert 0.015 < float(np.median(np.diff(joint_times))) < 0.03
    kinds = [kind for _, kind, _ in messages]
    statuses = [i for i, kind in enumerate(kinds) if kind == sm.STATUS]
    # dataStreamer.pgx: the first STATUS follows the 6th JOINT_POSITION, then every 5th.
    assert statuses[0] == 6
    assert all(b - a == 6 for a, b in zip(statuses, statuses[1:]))
    assert sm.decode_status(messages[statuses[0]][2]) == sm.RobotStatus(1, 0, 0, 0, 0, 2, 1)
    np.testing.assert_array_equal(sm.decode_joint_position(messages[0][2]), Q0)


def test_move_is_joint_linear(emu: Val3Emulator) -> None:
    motion, state = connected(emu)
    assert request(motion, point(0, GOAL, velocity=0.02)) == (0, sm.SUCCESS)
    samples, in_motion = [], []
    goal32 = GOAL.astype(np.float32).astype(float)
    while True:
        _, kind, body = state.next()
        if kind == sm.STATUS:
            in_motion.append(sm.decode_status(body).in_motion)
            if in_motion[-1] == 0 and samples and np.allclose(samples[-1], goal32, atol=1e-6):
                break
        else:
            samples.append(sm.decode_joint_position(body))
    samples = np.array(samples)
    s = samples @ GOAL / (GOAL @ GOAL)  # the path parameter of each sample
    assert np.abs(samples - np.outer(s, GOAL)).max() < 1e-5
    assert np.all((s >= -1e-7) & (s <= 1 + 1e-7)) and np.all(np.diff(s) >= -1e-7)
    assert np.count_nonzero((s > 0.01) & (s < 0.99)) >= 5  # seen along the way
    assert 1 in in_motion and in_motion[-1] == 0
    assert np.abs(emu.joint_positions() - goal32).max() < 1e-6
    assert emu.status().in_motion == 0


def test_queue_depth(emu: Val3Emulator) -> None:
    motion, _ = connected(emu)
    emu.hold_queue(True)
    replies = [request(motion, point(i, GOAL * 0.01 * i)) for i in range(11)]
    assert replies == [(i, sm.SUCCESS) for i in range(10)] + [(10, sm.FAILURE)]
    emu.hold_queue(False)
    time.sleep(0.1)
    assert request(motion, point(11, Q0)) == (11, sm.SUCCESS)


def test_refused_points(emu: Val3Emulator) -> None:
    motion, _ = connected(emu)
    beyond = np.array(RX60().upper_limits_rad) + np.array([0, 0, 0, 0, 0.01, 0])
    assert request(motion, point(1, beyond)) == (1, sm.FAILURE)
    assert request(motion, point(2, GOAL, velocity=0.0)) == (2, sm.FAILURE)
    assert request(motion, point(3, GOAL, velocity=-0.3)) == (3, sm.FAILURE)
    # pushMotion.pgx clamps the velocity to 100 %: too fast is accepted.
    assert request(motion, point(4, GOAL * 0.1, velocity=5.0)) == (4, sm.SUCCESS)


def test_topic_and_length_prefix(emu: Val3Emulator) -> None:
    """pushMotion.pgx replies only to SERVICE_REQUEST, but queues a TOPIC point all the same;
    the receiver never reads the length prefix (the type alone sets the body size)."""
    motion, _ = connected(emu)
    body = sm.encode_traj_pt(sm.JointTrajPt(1, GOAL * 0.05, 0.5))[16:]
    motion.sendall(sm.packet(sm.Header(sm.JOINT_TRAJ_PT, sm.TOPIC, sm.INVALID), body))
    assert nothing_arrives(motion, 0.2)
    np.testing.assert_allclose(emu.joint_positions(), GOAL * 0.05, atol=1e-6)
    wrong_length = struct.pack("<i", 999) + point(2, Q0)[4:]
    assert request(motion, wrong_length) == (2, sm.SUCCESS)


def test_stop_trajectory(emu: Val3Emulator) -> None:
    motion, _ = connected(emu)
    assert request(motion, point(0, GOAL, velocity=0.02)) == (0, sm.SUCCESS)
    assert request(motion, point(1, -GOAL, velocity=0.02)) == (1, sm.SUCCESS)
    wait_moving(emu, Q0)
    assert request(motion, point(sm.STOP_TRAJECTORY, Q0)) == (sm.STOP_TRAJECTORY, sm.SUCCESS)
    time.sleep(0.02)
    q = assert_still(emu, 0.3)  # the queued second point is gone too
    assert 0.0 < q @ GOAL / (GOAL @ GOAL) < 1.0
    assert emu.status().in_motion == 0


def test_state_disconnect_stops_motion(emu: Val3Emulator) -> None:
    motion, state = connected(emu)
    request(motion, point(0, GOAL, velocity=0.02))
    request(motion, point(1, -GOAL, velocity=0.02))
    wait_moving(emu, Q0)
    state.sock.close()
    time.sleep(0.05)
    assert_still(emu)
    # Reconnected, the arm does not resume: motionControl.pgx cleared the queues.
    StateReader(emu).joints()
    assert_still(emu)
    # drop_connections: both clients see the connection closed; the arm stays still.
    emu.drop_connections()
    assert motion.recv(1) == b""
    assert_still(emu, 0.05)


def test_e_stop(emu: Val3Emulator) -> None:
    motion, state = connected(emu)
    request(motion, point(0, GOAL, velocity=0.02))
    wait_moving(emu, Q0)
    emu.e_stop()
    assert_still(emu)
    assert emu.status() == sm.RobotStatus(0, 1, 0, 0, 0, 2, 0)
    state.wait_status(sm.RobotStatus(0, 1, 0, 0, 0, 2, 0))
    assert request(motion, point(1, Q0)) == (1, sm.FAILURE)
    emu.reset_e_stop()
    state.wait_status(sm.RobotStatus(1, 0, 0, 0, 0, 2, 1))
    assert request(motion, point(2, Q0)) == (2, sm.SUCCESS)


def test_ping_desynchronises_the_server(emu: Val3Emulator) -> None:
    """recvMsgBody.pgx reads a body only for JOINT_TRAJ_PT: a PING's 40 body bytes are read as
    the next headers (16 bytes a time, type 0: ignored), leaving the stream 8 bytes out of step.
    Each following 68-byte point moves it 4 more (68 = 4 x 16 + 4), so the next two points are
    read as garbage headers, never acknowledged nor executed; only after 56 + 2 x 68 = 12 x 16
    bytes is the stream aligned again and the third point is acknowledged."""
    motion, _ = connected(emu)
    ping = sm.packet(sm.Header(sm.PING, sm.SERVICE_REQUEST, sm.INVALID), bytes(40))
    motion.sendall(ping)
    for seq in (1, 2):
        motion.sendall(point(seq, GOAL * 0.1))
        assert nothing_arrives(motion, 0.3)
    assert emu.received == []
    assert request(motion, point(3, GOAL * 0.1)) == (3, sm.SUCCESS)
    assert [p.sequence for p in emu.received] == [3]


def test_split_writes(emu: Val3Emulator) -> None:
    motion, state = connected(emu)
    emu.set_split_writes(True)
    # The reply arrives in 1-3 byte pieces; an exact-count read still gets it whole.
    motion.sendall(point(1, GOAL * 0.1))
    expected = sm.encode_traj_pt_reply(1, sm.SUCCESS)
    assert sm.recv_exact(motion, len(expected)) == expected
    state.joints()  # the stream decodes too
    emu.set_split_writes(False)
    # A request sent in pieces, with pauses inside its fields, is accepted: recvData.pgx waits
    # for the rest of a field once its first byte came.
    packet = point(2, GOAL * 0.2)
    for a, b in ((0, 2), (2, 9), (9, 30), (30, 68)):
        motion.sendall(packet[a:b])
        time.sleep(0.02)
    assert sm.read_packet(motion, {sm.JOINT_TRAJ_PT})[0].reply_code == sm.SUCCESS
    # But a pause between header and body loses the message: the receiver finds no body byte
    # and resets (recvData.pgx, recvMsgBody.pgx), then reads the body as three headers and a
    # prefix (52 = 3 x 16 + 4), all ignored; the prefix is dropped in turn when no header
    # follows, which happens to leave the stream in step again.
    packet = point(3, GOAL * 0.3)
    motion.sendall(packet[:16])
    time.sleep(0.05)
    motion.sendall(packet[16:])
    assert nothing_arrives(motion, 0.2)
    assert [p.sequence for p in emu.received] == [1, 2]
    assert request(motion, point(4, GOAL * 0.1)) == (4, sm.SUCCESS)


def test_stall_state(emu: Val3Emulator) -> None:
    state = StateReader(emu)
    state.joints()
    emu.stall_state(0.4)
    time.sleep(0.03)
    state.drain()  # what was sent before the stall
    assert nothing_arrives(state.sock, 0.3)
    state.joints()  # resumes by itself
    emu.stall_state(None)
    time.sleep(0.03)
    state.drain()
    assert nothing_arrives(state.sock, 0.2)
    emu.resume_state()
    state.joints()


def test_offset_replacement_and_mirror() -> None:
    mirrored: list[np.ndarray] = []
    with Val3Emulator(SETTINGS, Q0, on_joints=mirrored.append) as emu:
        _, state = connected(emu)
        emu.set_reported_offset(np.full(6, 0.01))
        state.wait_joints(np.full(6, 0.01))
        np.testing.assert_array_equal(emu.joint_positions(), Q0)
        # A second motion client replaces the first, which sees its connection closed.
        first = connect(emu.motion_address)
        time.sleep(0.05)
        second = connect(emu.motion_address)
        assert first.recv(1) == b""
        assert request(second, point(1, GOAL * 0.05)) == (1, sm.SUCCESS)
        time.sleep(0.2)
    assert mirrored and np.allclose(mirrored[-1], (GOAL * 0.05).astype(np.float32), atol=1e-7)


def test_arm_trapezoid() -> None:
    speed = np.array(RX60().velocity_limits_rad_s)
    arm = Arm(Q0, speed, ACCELERATION_TIME_S, queue_depth=2)
    goal = np.array([1.0, 0, 0, 0, 0, 0])
    assert arm.push(MoveJ(goal, 50.0)) and arm.push(MoveJ(Q0, 100.0))
    assert not arm.push(MoveJ(goal, 10.0))
    dt_s, rates = 0.001, []
    q_prev = arm.joints
    while arm.in_motion and len(rates) < 10_000:
        q = arm.step(dt_s)
        rates.append((q[0] - q_prev[0]) / dt_s)
        q_prev = q
    assert not arm.in_motion
    np.testing.assert_array_equal(arm.joints, Q0)
    v_half = 0.5 * speed[0]
    assert max(rates) == pytest.approx(v_half, rel=1e-6)  # cruise at 50 %
    # Back at 100 %, a triangular profile: 1 rad is too short to reach the nominal speed.
    assert min(rates) == pytest.approx(-np.sqrt(speed[0] / ACCELERATION_TIME_S), rel=1e-2)
    accel = np.abs(np.diff(rates)) / dt_s
    assert accel.max() <= speed[0] / ACCELERATION_TIME_S * 1.01  # accel stays nominal
