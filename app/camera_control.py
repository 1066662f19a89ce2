"""Viewer camera: orbit and fly navigation, snapping to rig cameras.

The pose is kept as an eye position plus yaw/pitch about a world "up" axis (taken from the rig:
OpenCV cameras look with image-up = camera -y). Snapping to a rig camera keeps that camera's
exact pose and intrinsics until the user moves, so what the viewer shows there is comparable
pixel for pixel with the camera's ground truth.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from fixer4d.geometry.camera import Camera

# Pitch is kept this far from +-90 degrees so that the up vector never aligns with the view.
PITCH_LIMIT = math.radians(89.0)
# Radians of yaw/pitch per pixel of mouse drag when the viewport size is unknown.
ROTATE_SPEED = 0.005
# Orbit sensitivity scaled by the viewport: a drag across the viewport's height turns the view
# by this angle (90 degrees: a 200 px drag in a 430 px viewport is ~40 degrees, where a fixed
# 0.005 rad/px made it ~57 and users overshot).
ORBIT_RADIANS_PER_VIEWPORT = math.pi / 2.0
# Orbit distance factor per mouse-wheel notch (10% closer/farther).
ZOOM_STEP = 1.1
# Shortest orbit distance, relative to the scene radius: the eye never reaches the target.
MIN_DISTANCE_FRACTION = 1e-3
DEFAULT_FOV_Y = math.radians(50.0)


def _basis(up: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """An orthonormal frame (e1, e2, up) with up the given unit vector."""
    up = up / np.linalg.norm(up)
    helper = np.array([1.0, 0.0, 0.0]) if abs(up[0]) < 0.9 else np.array([0.0, 0.0, 1.0])
    e1 = np.cross(up, helper)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(up, e1)
    return e1, e2, up


@dataclass
class ViewCamera:
    """Interactive camera. ``mode`` is "orbit" (rotate about ``target``) or "fly" (rotate in
    place, move along the view). Angles in radians, positions in world units."""

    target: np.ndarray = field(default_factory=lambda: np.zeros(3))
    distance: float = 4.0
    yaw: float = 0.0
    pitch: float = 0.0
    up: np.ndarray = field(default_factory=lambda: np.array([0.0, -1.0, 0.0]))
    fov_y: float = DEFAULT_FOV_Y
    mode: str = "orbit"
    scene_radius: float = 1.0
    # a rig camera we snapped to: its exact pose/intrinsics are used until the next move
    snapped: Camera | None = None

    # ---- pose -------------------------------------------------------------------------------
    def forward(self) -> np.ndarray:
        e1, e2, up = _basis(np.asarray(self.up, float))
        cp = math.cos(self.pitch)
        return cp * math.cos(self.yaw) * e1 + cp * math.sin(self.yaw) * e2 + math.sin(self.pitch) * up

    def eye(self) -> np.ndarray:
        return np.asarray(self.target, float) - self.distance * self.forward()

    def camera(self, width: int, height: int, name: str = "viewer") -> Camera:
        """The current view as a ``Camera`` of the given size; a snapped rig camera keeps its
        exact pose and intrinsics, letterboxed into width x height (``letterbox``: its own
        aspect, so the result may be narrower or shorter than asked)."""
        if self.snapped is not None:
            return letterbox(self.snapped, width, height)
        eye = self.eye()
        return Camera.look_at(eye, eye + self.forward(), up=self.up, fov_y=self.fov_y, width=width,
                              height=height, name=name)

    def _unsnap(self) -> None:
        self.snapped = None

    def snap_to(self, cam: Camera) -> None:
        """Jump to a rig camera's pose and intrinsics; the orbit target moves to the point the
        camera looks at at the current orbit distance."""
        e1, e2, up = _basis(np.asarray(self.up, float))
        f = cam.forward
        self.pitch = float(np.clip(math.asin(np.clip(f @ up, -1.0, 1.0)), -PITCH_LIMIT, PITCH_LIMIT))
        self.yaw = math.atan2(float(f @ e2), float(f @ e1))
        self.target = cam.center + self.distance * self.forward()
        self.fov_y = cam.fov_y
        self.snapped = cam

    def look_from(self, eye: np.ndarray, target: np.ndarray, scene_radius: float | None = None) -> None:
        """Orbit about ``target`` from ``eye``."""
        if scene_radius is not None:
            self.scene_radius = max(float(scene_radius), 1e-6)
        e1, e2, up = _basis(np.asarray(self.up, float))
        d = np.asarray(target, float) - np.asarray(eye, float)
        self.distance = max(float(np.linalg.norm(d)), MIN_DISTANCE_FRACTION * self.scene_radius)
        f = d / self.distance
        self.pitch = float(np.clip(math.asin(np.clip(f @ up, -1.0, 1.0)), -PITCH_LIMIT, PITCH_LIMIT))
        self.yaw = math.atan2(float(f @ e2), float(f @ e1))
        self.target = np.asarray(target, float)
        self.snapped = None

    # ---- input ------------------------------------------------------------------------------
    def rotate(self, dx: float, dy: float, viewport_px: float | None = None) -> None:
        """Mouse drag by (dx, dy) pixels: orbit about the target, or look around in fly mode;
        ``viewport_px`` (the viewport's height) scales the rate (ORBIT_RADIANS_PER_VIEWPORT)."""
        rate = ROTATE_SPEED if not viewport_px else ORBIT_RADIANS_PER_VIEWPORT / max(float(viewport_px), 1.0)
        eye = self.eye()
        self._unsnap()
        self.yaw -= rate * dx
        self.pitch = float(np.clip(self.pitch - rate * dy, -PITCH_LIMIT, PITCH_LIMIT))
        if self.mode == "fly":  # keep the eye, move the target
            self.target = eye + self.distance * self.forward()

    def pan(self, dx: float, dy: float, height: int) -> None:
        """Move target and eye in the image plane so the scene follows the mouse."""
        self._unsnap()
        cam = self.camera(max(height, 1), max(height, 1))
        scale = self.distance * 2.0 * math.tan(self.fov_y / 2.0) / max(height, 1)
        self.target = np.asarray(self.target, float) - scale * (dx * cam.c2w[:3, 0] + dy * cam.c2w[:3, 1])

    def zoom(self, notches: float) -> None:
        """Mouse wheel: orbit mode changes the distance; fly mode moves along the view."""
        self._unsnap()
        if self.mode == "orbit":
            self.distance = max(self.distance * ZOOM_STEP ** (-notches), MIN_DISTANCE_FRACTION * self.scene_radius)
        else:
            self.move(notches * 0.1 * self.scene_radius, 0.0, 0.0)

    def move(self, forward: float, right: float, up: float) -> None:
        """Fly: translate eye and target (world units) along view, right and up."""
        self._unsnap()
        f = self.forward()
        r = np.cross(f, -np.asarray(self.up, float))
        r /= np.linalg.norm(r)
        u = np.asarray(self.up, float) / np.linalg.norm(self.up)
        self.target = np.asarray(self.target, float) + forward * f + right * r + up * u

    # ---- persistence ------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        return {"target": np.asarray(self.target, float).tolist(), "distance": self.distance, "yaw": self.yaw,
                "pitch": self.pitch, "up": np.asarray(self.up, float).tolist(), "fov_y": self.fov_y,
                "mode": self.mode, "scene_radius": self.scene_radius,
                "snapped": None if self.snapped is None else self.snapped.to_dict()}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "ViewCamera":
        snapped = d.get("snapped")
        return cls(target=np.asarray(d["target"], float), distance=float(d["distance"]), yaw=float(d["yaw"]),
                   pitch=float(d["pitch"]), up=np.asarray(d["up"], float), fov_y=float(d["fov_y"]),
                   mode=str(d.get("mode", "orbit")), scene_radius=float(d.get("scene_radius", 1.0)),
                   snapped=None if snapped is None else Camera.from_dict(snapped))


def letterbox(cam: Camera, width: int, height: int) -> Camera:
    """``cam`` scaled uniformly to the largest image of its own aspect that fits width x height
    (the rest of the viewport is bars): the same pose, K scaled with the image, so the view is
    ``cam``'s image resampled, never stretched."""
    s = min(width / cam.width, height / cam.height)
    w, h = max(1, int(round(cam.width * s))), max(1, int(round(cam.height * s)))
    return cam if (w, h) == (cam.width, cam.height) else cam.resized(w, h)


def rig_up(cameras: list[Camera]) -> np.ndarray:
    """World up as the rig sees it: the mean of the cameras' image-up directions (-y in OpenCV)."""
    u = -np.mean([c.c2w[:3, 1] for c in cameras], axis=0)
    n = np.linalg.norm(u)
    return u / n if n > 1e-9 else np.array([0.0, -1.0, 0.0])
