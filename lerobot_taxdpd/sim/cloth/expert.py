"""Scripted expert: hangs the cloth by a chosen hole on a chosen hanger, by gripper position control.

It reads privileged state (mesh vertices, hanger geometry) and, like the paper's demonstrator, keeps soft
constraints while it moves: (i) it turns the cloth smoothly until it faces the peg, (ii) it keeps the
grippers about one cloth width apart and (iii) at the same height.

A hanging cloth is a pendulum with almost no damping, so the expert never chases the swinging hole.
It steers the grippers' midpoint, under speed and acceleration limits, to where the hole would be at the
target if the cloth hung still (the hole's offset below the grippers is measured at the start), plus a
slow integral of the remaining error; and it damps the swing as a crane operator does, moving the
grippers towards the side the hole has swung to.

Phases: approach (turn and bring the hole to an entry point on the peg's axis, in front of its tip),
thread (slide the hole along the axis to the goal point, pausing before the tip until it is on the axis),
hold (keep it there, still damping, until the env lets go).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from lerobot_taxdpd.sim.cloth.env import ClothHangEnv


@dataclass(frozen=True)
class ExpertGains:
    approach_speed: float = 1.5  # m/s
    thread_speed: float = 0.7  # m/s
    max_acceleration: float = 1.5  # m/s^2
    turn_rate: float = 0.6  # rad/s
    position_gain: float = 2.5  # 1/s, midpoint towards its reference
    sway_gain: float = 1.5  # 1/s, midpoint towards the swung-out hole
    integral_gain: float = 1.0  # 1/s, reference drift that removes the remaining hole error
    integral_radius: float = 0.4  # metres: integrate only this close to the target
    entry_distance: float = 1.2  # metres in front of the peg tip, on its axis, where threading starts
    entry_tolerance: float = 0.3  # metres from the entry point to start threading
    detour_ratio: float = 0.5  # while approaching, aim this much further out per metre off the peg's axis
    max_detour: float = 1.0  # metres
    tip_clearance: float = 0.4  # the hole waits this far in front of the tip until it is on the axis
    align_tolerance: float = 0.1  # metres off the peg's axis allowed when passing the tip
    width_ratio: float = 1.0  # gripper spacing / cloth width
    spacing_rate: float = 0.2  # m/s


def wrap_angle(angle: float) -> float:
    return (angle + math.pi) % (2 * math.pi) - math.pi


def lateral_axis(angle: float) -> np.ndarray:
    return np.array([math.cos(angle), math.sin(angle), 0.0])


class ScriptedExpert:
    """Call `act()` once per env step; `hole` and `hanger` index the scene's holes and hangers."""

    def __init__(self, env: ClothHangEnv, hole: int, hanger: int, gains: ExpertGains | None = None) -> None:
        if not 0 <= hole < len(env.scene.holes):
            raise ValueError(f"hole: index {hole} out of range for a cloth with {len(env.scene.holes)} hole(s)")
        if not 0 <= hanger < len(env.scene.hangers):
            raise ValueError(f"hanger: index {hanger} out of range for {len(env.scene.hangers)} hangers")
        self.env = env
        self.hole = hole
        self.hanger = env.scene.hangers[hanger]
        self.gains = gains or ExpertGains()
        self.phase = "approach"
        heading = self.hanger.heading
        self._target_angle = math.atan2(-heading[0], heading[1])  # the lateral axis heading x z faces the peg
        self._spacing = self.gains.width_ratio * env.scene.cloth_width
        grippers = env.gripper_positions()
        self._offset = self._to_gripper_frame(env.hole_centroids()[hole] - grippers.mean(axis=0), grippers)
        self._bias = np.zeros(3)
        self._velocity = np.zeros(3)
        self._thread_progress = 0.0

    def act(self) -> np.ndarray:
        g, dt = self.gains, self.env.settings.control_period
        grippers = self.env.gripper_positions()
        midpoint = grippers.mean(axis=0)
        centroid = self.env.hole_centroids()[self.hole]
        angle = self._angle(grippers)
        target, speed = self._target(centroid, angle, dt)

        error = target - centroid
        if np.linalg.norm(error) < g.integral_radius:
            self._bias += g.integral_gain * dt * error
        offset = self._from_gripper_frame(self._offset, self._target_angle)
        reference = target - offset + self._bias
        wanted = g.position_gain * (reference - midpoint)
        wanted *= min(1.0, speed / max(np.linalg.norm(wanted), 1e-9))
        change = wanted - self._velocity
        change *= min(1.0, g.max_acceleration * dt / max(np.linalg.norm(change), 1e-9))
        self._velocity = self._velocity + change

        sway = (centroid - midpoint) - self._from_gripper_frame(self._offset, angle)
        sway[2] = 0.0
        step = (self._velocity + g.sway_gain * sway) * dt

        turn = float(np.clip(wrap_angle(self._target_angle - angle), -g.turn_rate * dt, g.turn_rate * dt))
        spacing = float(np.linalg.norm(grippers[1] - grippers[0]))
        spacing += float(np.clip(self._spacing - spacing, -g.spacing_rate * dt, g.spacing_rate * dt))
        new_midpoint = midpoint + step
        axis = lateral_axis(angle + turn)
        goal = np.stack([new_midpoint - 0.5 * spacing * axis, new_midpoint + 0.5 * spacing * axis])
        return (goal - grippers).reshape(6).astype(np.float32)

    def _target(self, centroid: np.ndarray, angle: float, dt: float) -> tuple[np.ndarray, float]:
        """Where the hole should be now, and how fast the grippers may go."""
        g, h = self.gains, self.hanger
        entry = h.peg_tip + g.entry_distance * h.peg_direction
        if self.phase == "approach":
            near = np.linalg.norm(centroid - entry) < g.entry_tolerance
            if near and abs(wrap_angle(self._target_angle - angle)) < 0.1:
                self.phase = "thread"
            else:
                # Far off the axis, aim further out so the sweeping cloth stays clear of the peg tip.
                offset = centroid - h.peg_root
                off_axis = np.linalg.norm(offset - (offset @ h.peg_direction) * h.peg_direction)
                detour = min(g.max_detour, g.detour_ratio * off_axis)
                return entry + detour * h.heading, g.approach_speed
        path = h.goal_point - entry
        length = float(np.linalg.norm(path))
        direction = path / length
        offset = centroid - entry
        off_axis = np.linalg.norm(offset - (offset @ direction) * direction)
        before_tip = length - (h.goal_point - h.peg_tip) @ direction - g.tip_clearance
        if self._thread_progress < before_tip or off_axis < g.align_tolerance:
            self._thread_progress = min(length, self._thread_progress + g.thread_speed * dt)
        if self._thread_progress >= length:
            self.phase = "hold"
        return entry + direction * self._thread_progress, g.thread_speed

    def _to_gripper_frame(self, vector: np.ndarray, grippers: np.ndarray) -> np.ndarray:
        axis = lateral_axis(self._angle(grippers))
        normal = np.cross([0.0, 0.0, 1.0], axis)
        return np.array([vector @ axis, vector @ normal, vector[2]])

    @staticmethod
    def _from_gripper_frame(local: np.ndarray, angle: float) -> np.ndarray:
        axis = lateral_axis(angle)
        normal = np.cross([0.0, 0.0, 1.0], axis)
        return local[0] * axis + local[1] * normal + np.array([0.0, 0.0, local[2]])

    @staticmethod
    def _angle(grippers: np.ndarray) -> float:
        lateral = grippers[1] - grippers[0]
        return math.atan2(lateral[1], lateral[0])
