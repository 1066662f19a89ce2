"""pycolmap for the calibration package: the import that keeps fixer4d's signal handlers, and
conversions between COLMAP camera models and ``RigCamera``.

COLMAP puts the centre of the top-left pixel at (0.5, 0.5), like ``fixer4d.geometry.camera``, so
principal points carry over unchanged.
"""
from __future__ import annotations

import contextlib
from typing import Iterator

import numpy as np

from fixer4d.calib.rig import RigCamera
from fixer4d.errors import BackendUnavailable, InputError

# COLMAP model -> (names of its parameters in order). Each maps onto OpenCV's radial-tangential model.
MODEL_PARAMS = {
    "SIMPLE_PINHOLE": ("f", "cx", "cy"),
    "PINHOLE": ("fx", "fy", "cx", "cy"),
    "SIMPLE_RADIAL": ("f", "cx", "cy", "k1"),
    "RADIAL": ("f", "cx", "cy", "k1", "k2"),
    "OPENCV": ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2"),
}


def pycolmap_module():
    """``import pycolmap``, then give Python's stop-signal handlers back (its glog takes SIGTERM on import)."""
    try:
        import pycolmap
    except ImportError as exc:  # pragma: no cover - pycolmap is a declared dependency
        raise BackendUnavailable("pycolmap is not installed; install fixer4d[init] (pip install pycolmap)") from exc
    from fixer4d.signals import reassert_python_handlers

    reassert_python_handlers()
    return pycolmap


@contextlib.contextmanager
def quiet(pycolmap) -> Iterator[None]:
    """COLMAP logs every step at INFO through glog; keep warnings and errors only."""
    old = pycolmap.logging.minloglevel
    pycolmap.logging.minloglevel = 2
    try:
        yield
    finally:
        pycolmap.logging.minloglevel = old


def rig_camera_from_colmap(camera, name: str, w2c: np.ndarray, label: str) -> RigCamera:
    """A pycolmap Camera + (4, 4) world-to-camera -> RigCamera; InputError for a lens model
    OpenCV's radial-tangential model cannot express (fisheye, thin-prism, ...)."""
    model = camera.model.name if hasattr(camera.model, "name") else str(camera.model)
    if model not in MODEL_PARAMS:
        raise InputError(f"{label}: camera model {model} of image {name!r} is not supported; use one of "
                         f"{sorted(MODEL_PARAMS)} (COLMAP's image_undistorter writes PINHOLE)")
    p = dict(zip(MODEL_PARAMS[model], (float(v) for v in camera.params)))
    fx = p.get("fx", p.get("f"))
    fy = p.get("fy", p.get("f"))
    K = np.array([[fx, 0.0, p["cx"]], [0.0, fy, p["cy"]], [0.0, 0.0, 1.0]])
    dist = {k: p[k] for k in ("k1", "k2", "p1", "p2") if k in p}
    return RigCamera(name, int(camera.width), int(camera.height), K, w2c, dist)


def colmap_params(cam: RigCamera, model: str) -> list[float]:
    """RigCamera -> the parameter list of a COLMAP ``model`` (for writing a model or a database)."""
    values = {"f": 0.5 * (cam.K[0, 0] + cam.K[1, 1]), "fx": cam.K[0, 0], "fy": cam.K[1, 1], "cx": cam.K[0, 2],
              "cy": cam.K[1, 2], **cam.distortion}
    return [float(values[k]) for k in MODEL_PARAMS[model]]
