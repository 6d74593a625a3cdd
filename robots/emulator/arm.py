"""The emulated arm's motion: what the controller does with the movej commands it is given.

The VAL 3 server (motionControl.pgx) hands every point to `movej` with the MotionCmd's mdesc:
blend off (leave=0, reach=0), `vel` set from the point (pushMotion.pgx) and `accel`/`decel` left at
their default of 100 % of nominal. A movej moves joint-linearly (all joints start and stop
together, on the straight segment in joint space), the most limiting joint at its allowed speed,
with a trapezoidal speed profile, and with blend off it stops at each point. This module is pure
(no clock, no socket): the caller advances it with `step`.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True, eq=False)
class MoveJ:
    """A movej to `joints_rad` at `speed_percent` of each joint's nominal speed and
    `accel_percent` of its nominal acceleration (the VAL 3 mdesc vel / accel fields)."""

    joints_rad: np.ndarray
    speed_percent: float
    accel_percent: float = 100.0


@dataclass(frozen=True, eq=False)
class _Segment:
    """One movej in progress: q(t) = q_start + s(t) * dq, s rising from 0 to 1 in `duration_s`
    with path acceleration `accel` (1/s^2) up to path speed `speed` (1/s)."""

    q_start_rad: np.ndarray
    dq_rad: np.ndarray
    accel: float
    speed: float
    ramp_s: float
    duration_s: float

    def s(self, t_s: float) -> float:
        if t_s <= self.ramp_s:
            return 0.5 * self.accel * t_s**2
        if t_s < self.duration_s - self.ramp_s:
            return 0.5 * self.accel * self.ramp_s**2 + self.speed * (t_s - self.ramp_s)
        return 1.0 - 0.5 * self.accel * (self.duration_s - t_s) ** 2


class Arm:
    """A 6-joint arm executing queued movej commands (at most `queue_depth` waiting, like the
    controller's motion stack; `push` refuses more)."""

    def __init__(
        self,
        q0_rad: np.ndarray,
        nominal_speed_rad_s: np.ndarray,
        acceleration_time_s: float,
        queue_depth: int = 10,
    ) -> None:
        self._q_rad = np.array(q0_rad, dtype=float)
        self._speed_rad_s = np.asarray(nominal_speed_rad_s, dtype=float)
        # Each joint reaches its nominal speed in acceleration_time_s at 100 % accel.
        self._accel_rad_s2 = self._speed_rad_s / acceleration_time_s
        self._queue: deque[MoveJ] = deque()
        self._queue_depth = queue_depth
        self._segment: _Segment | None = None
        self._goal_rad: np.ndarray | None = None
        self._elapsed_s = 0.0

    @property
    def joints(self) -> np.ndarray:
        return self._q_rad.copy()

    @property
    def in_motion(self) -> bool:
        """True while moving or while moves are queued (VAL 3 isSettled() is false)."""
        return self._segment is not None or bool(self._queue)

    @property
    def queued(self) -> int:
        return len(self._queue)

    def push(self, move: MoveJ) -> bool:
        """Queue a move; False when the queue is full (the caller keeps it and retries)."""
        if len(self._queue) >= self._queue_depth:
            return False
        self._queue.append(move)
        return True

    def stop(self) -> None:
        """resetMotion(): drop the move in progress and every queued one; the arm holds where it
        is (the emulated stop is instantaneous)."""
        self._queue.clear()
        self._segment = None
        self._goal_rad = None
        self._elapsed_s = 0.0

    def step(self, dt_s: float) -> np.ndarray:
        """Advance the arm by dt_s seconds; time left over at the end of a move goes to the
        next one (blend off: the arm stops at the point, then starts the next move)."""
        remaining_s = dt_s
        while True:
            if self._segment is None:
                if not self._queue:
                    break
                self._start(self._queue.popleft())
                continue
            assert self._goal_rad is not None
            self._elapsed_s += remaining_s
            if self._elapsed_s >= self._segment.duration_s:
                # Land exactly on the goal, not on q_start + 1.0 * dq (rounding).
                self._q_rad = self._goal_rad.copy()
                remaining_s = self._elapsed_s - self._segment.duration_s
                self._segment, self._goal_rad, self._elapsed_s = None, None, 0.0
                continue
            s = self._segment.s(self._elapsed_s)
            self._q_rad = self._segment.q_start_rad + s * self._segment.dq_rad
            break
        return self.joints

    def _start(self, move: MoveJ) -> None:
        goal_rad = np.asarray(move.joints_rad, dtype=float).copy()
        dq_rad = goal_rad - self._q_rad
        moving = np.abs(dq_rad) > 0.0
        self._goal_rad, self._elapsed_s = goal_rad, 0.0
        if not moving.any():
            self._segment = _Segment(self._q_rad.copy(), dq_rad, 1.0, 1.0, 0.0, 0.0)
            return
        span = np.abs(dq_rad[moving])
        # Path-parameter limits: the most limiting joint sets them, so all joints stay in step.
        speed = float(np.min(move.speed_percent / 100.0 * self._speed_rad_s[moving] / span))
        accel = float(np.min(move.accel_percent / 100.0 * self._accel_rad_s2[moving] / span))
        if speed**2 / accel >= 1.0:
            # Triangular profile: the top speed is never reached on this short move.
            ramp_s = float(np.sqrt(1.0 / accel))
            speed, duration_s = accel * ramp_s, 2.0 * ramp_s
        else:
            ramp_s = speed / accel
            duration_s = ramp_s + 1.0 / speed
        self._segment = _Segment(self._q_rad.copy(), dq_rad, accel, speed, ramp_s, duration_s)
