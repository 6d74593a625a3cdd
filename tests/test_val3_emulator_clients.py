"""The emulator against clients that abuse it: one that sends part of a message and falls
silent, one that never reads what it is sent, a flood of points; and the points the VAL 3 server
meets although no driver should send them (a velocity of 1e-38, NaN and infinities)."""

from __future__ import annotations

import logging
import math
import socket
import struct
import threading
import time
from dataclasses import replace

import numpy as np
import pytest

from robots.drivers import simple_message as sm
from robots.emulator.val3_server import EmulatorSettings, Val3Emulator
from tests.test_val3_emulator import READ_TIMEOUT_S, connect, point, request

Q0 = np.zeros(6)
LIMIT_S = 0.3
SETTINGS = EmulatorSettings(
    motion_port=0, state_port=0, connect_delay_s=0.05, time_scale=20.0, client_timeout_s=LIMIT_S
)


def closed_within(sock: socket.socket, seconds: float) -> bool:
    """The emulator closed `sock` within `seconds` (whatever it sent before is skipped)."""
    deadline_s = time.monotonic() + seconds
    while time.monotonic() < deadline_s:
        sock.settimeout(max(0.01, deadline_s - time.monotonic()))
        try:
            if not sock.recv(65536):
                return True
        except TimeoutError:
            return False
        except OSError:
            return True
    return False


def drops(caplog: pytest.LogCaptureFixture) -> list[str]:
    return [r.getMessage() for r in caplog.records if "dropped the client" in r.getMessage()]


def dropped_within(caplog: pytest.LogCaptureFixture, seconds: float) -> list[str]:
    """The drops logged, waiting up to `seconds` for one (without reading from the client)."""
    deadline_s = time.monotonic() + seconds
    while not drops(caplog) and time.monotonic() < deadline_s:
        time.sleep(0.01)
    return drops(caplog)


@pytest.fixture
def emu():
    with Val3Emulator(SETTINGS, Q0) as emulator:
        yield emulator


def test_a_client_silent_after_one_byte_does_not_keep_the_next_one_waiting(emu):
    silent = connect(emu.motion_address)
    silent.sendall(b"\x40")
    time.sleep(0.05)  # the receiver is now waiting for the rest of the prefix
    driver = connect(emu.motion_address)
    # Served as soon as it connects: a new client replaces the one that holds the port.
    assert request(driver, point(1, Q0 + 0.01)) == (1, sm.SUCCESS)
    assert closed_within(silent, READ_TIMEOUT_S)


def test_a_lone_half_sent_message_is_dropped_after_the_limit_and_logged(emu, caplog):
    caplog.set_level(logging.WARNING, logger="robots.emulator")
    client = connect(emu.motion_address)
    sent_s = time.monotonic()
    client.sendall(point(1, Q0)[:5])  # the prefix and one byte of the header
    assert closed_within(client, LIMIT_S + 1.0)
    assert time.monotonic() - sent_s >= LIMIT_S
    assert any("motion port" in m and "1 of 12 bytes of a field" in m for m in drops(caplog))
    # The port serves the next client.
    assert request(connect(emu.motion_address), point(2, Q0)) == (2, sm.SUCCESS)


def test_a_motion_client_that_never_reads_is_dropped_and_the_next_one_served(caplog):
    caplog.set_level(logging.WARNING, logger="robots.emulator")
    settings = replace(SETTINGS, send_buffer_bytes=4096)
    with Val3Emulator(settings, Q0) as emu:
        flooder = connect(emu.motion_address, receive_buffer_bytes=2048)
        refused = point(1, Q0, velocity=0.0)  # answered FAILURE: nothing is queued

        def flood():
            try:
                for _ in range(20_000):
                    flooder.sendall(refused)
            except OSError:
                pass  # dropped by the emulator

        threading.Thread(target=flood, daemon=True).start()
        logged = dropped_within(caplog, 10.0)
        assert any("motion port" in m and "took no 68-byte message" in m for m in logged)
        assert closed_within(flooder, READ_TIMEOUT_S)
        assert request(connect(emu.motion_address), point(2, Q0)) == (2, sm.SUCCESS)


def test_a_state_client_that_never_reads_is_dropped_and_the_next_one_streamed(caplog):
    caplog.set_level(logging.WARNING, logger="robots.emulator")
    # JOINT_POSITION every 2 ms fills a 4 kB send buffer within a second or so.
    settings = replace(SETTINGS, send_buffer_bytes=4096, joint_period_s=0.002)
    with Val3Emulator(settings, Q0) as emu:
        idle = connect(emu.state_address, receive_buffer_bytes=2048)
        logged = dropped_within(caplog, 10.0)
        assert any("state port" in m and "took no" in m for m in logged)
        assert closed_within(idle, READ_TIMEOUT_S)
        reader = connect(emu.state_address)
        header, _ = sm.read_packet(reader, {sm.JOINT_POSITION, sm.STATUS})
        assert header.msg_type == sm.JOINT_POSITION


def test_the_points_kept_are_bounded():
    with Val3Emulator(replace(SETTINGS, received_kept=50), Q0) as emu:
        client = connect(emu.motion_address)
        for seq in range(120):
            request(client, point(seq, Q0, velocity=0.0))
        kept = emu.received
        assert len(kept) == 50 and emu.received_count == 120
        assert [p.sequence for p in kept] == list(range(70, 120))


def test_a_velocity_of_1e_38_is_taken_and_holds_the_queue_as_the_server_does(emu):
    state = connect(emu.state_address)
    motion = connect(emu.motion_address)
    sm.read_packet(state, {sm.JOINT_POSITION, sm.STATUS})  # both ports up: motion runs
    assert request(motion, point(1, Q0 + 0.5, velocity=1e-38)) == (1, sm.SUCCESS)
    assert request(motion, point(2, Q0 - 0.5)) == (2, sm.SUCCESS)
    time.sleep(0.2)  # 4 s of emulated time: a move at 0.5 would be over
    assert np.abs(emu.joint_positions() - Q0).max() < 1e-9
    assert emu.status().in_motion == 1


@pytest.mark.parametrize(
    "offset, value, reply_code",
    [(44, math.nan, sm.FAILURE), (4, math.inf, sm.FAILURE), (44, math.inf, sm.SUCCESS)],
    ids=["NaN velocity", "infinite joint", "infinite velocity: 100 %"],
)
def test_non_finite_values_meet_the_servers_own_checks(emu, offset, value, reply_code):
    client = connect(emu.motion_address)
    packet = bytearray(point(7, Q0 + 0.1))
    packet[16 + offset : 16 + offset + 4] = struct.pack("<f", value)
    assert request(client, bytes(packet)) == (7, reply_code)
    assert [p.sequence for p in emu.received] == [7]
