"""Camera: projection conventions, round trips, resizing and the OpenGL boundary."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fixer4d.errors import InputError
from fixer4d.geometry import quaternion as quat
from fixer4d.geometry.camera import CV_TO_GL, Camera, rig_extent

finite = st.floats(-5.0, 5.0, allow_nan=False, allow_infinity=False)


@st.composite
def cameras(draw):
    q = np.array([draw(st.floats(-1, 1)) for _ in range(4)])
    if np.linalg.norm(q) < 1e-3:
        q = np.array([1.0, 0, 0, 0])
    c2w = np.eye(4)
    c2w[:3, :3] = quat.to_matrix(q)
    c2w[:3, 3] = [draw(finite) for _ in range(3)]
    w, h = draw(st.integers(1, 640)), draw(st.integers(1, 480))
    fx, fy = draw(st.floats(10, 2000)), draw(st.floats(10, 2000))
    K = np.array([[fx, 0, draw(st.floats(-50, 700))], [0, fy, draw(st.floats(-50, 500))], [0, 0, 1]])
    return Camera(K, c2w, w, h, "c")


def simple_camera(width=8, height=6) -> Camera:
    K = np.array([[10.0, 0.0, 4.0], [0.0, 10.0, 3.0], [0.0, 0.0, 1.0]])
    return Camera(K, np.eye(4), width, height, "simple")


def test_pixel_centre_convention_is_pinned():
    cam = simple_camera()
    # the optical axis hits K's principal point (4, 3): the corner shared by pixels (3..4, 2..3)
    uv, z = cam.project(np.array([[0.0, 0.0, 2.0]]))
    np.testing.assert_allclose(uv, [[4.0, 3.0]])
    assert z[0] == 2.0
    # the centre of pixel (0, 0) is at continuous (0.5, 0.5): its ray has x = (0.5 - 4) / 10
    np.testing.assert_allclose(cam.pixel_centers()[0, 0], [0.5, 0.5])
    np.testing.assert_allclose(cam.ray_directions()[0, 0], [-0.35, -0.25, 1.0])
    np.testing.assert_allclose(cam.backproject_depth(np.full((6, 8), 2.0))[2, 3], [-0.1, -0.1, 2.0])
    # integer pixel (u, v) covers [u, u+1): floor(uv) is the pixel index
    uv, _ = cam.project(cam.backproject(np.array([[7.5, 5.5]]), np.array([3.0])))
    assert tuple(np.floor(uv[0]).astype(int)) == (7, 5)


@settings(max_examples=60, deadline=None)
@given(cam=cameras(), u=st.floats(0, 1), v=st.floats(0, 1), z=st.floats(0.01, 100))
def test_project_backproject_round_trip(cam, u, v, z):
    uv = np.array([[u * cam.width, v * cam.height]])
    X = cam.backproject(uv, np.array([z]))
    uv2, z2 = cam.project(X)
    np.testing.assert_allclose(uv2, uv, atol=1e-6 * max(1.0, cam.width))
    np.testing.assert_allclose(z2, [z], rtol=1e-9)


@settings(max_examples=40, deadline=None)
@given(cam=cameras())
def test_depth_map_round_trip(cam):
    cam = cam.resized(min(cam.width, 16), min(cam.height, 12))
    depth = np.linspace(0.5, 4.0, cam.width * cam.height).reshape(cam.height, cam.width)
    pts = cam.backproject_depth(depth)
    uv, z = cam.project(pts.reshape(-1, 3))
    np.testing.assert_allclose(uv.reshape(cam.height, cam.width, 2), cam.pixel_centers(), atol=1e-7)
    np.testing.assert_allclose(z.reshape(depth.shape), depth, rtol=1e-10)


def test_points_behind_have_no_image():
    uv, z = simple_camera().project(np.array([[0.0, 0.0, -1.0], [0.0, 0.0, 0.0]]))
    assert np.isnan(uv).all() and z.tolist() == [-1.0, 0.0]


def test_resize_scales_intrinsics_and_keeps_pixel_centres():
    cam = simple_camera(8, 6)
    half = cam.resized(4, 3)
    np.testing.assert_allclose(half.K, [[5.0, 0, 2.0], [0, 5.0, 1.5], [0, 0, 1]])
    assert (half.width, half.height) == (4, 3)
    X = np.array([[0.3, -0.2, 2.5]])
    np.testing.assert_allclose(half.project(X)[0], cam.project(X)[0] / 2.0)
    # a 2x2 block of fine pixels shares the centre of its coarse pixel
    fine = cam.pixel_centers()[:2, :2].reshape(-1, 2).mean(0)
    np.testing.assert_allclose(fine / 2.0, half.pixel_centers()[0, 0])
    assert cam.scaled(0.5).width == 4 and cam.scaled(0.01).width == 1


@settings(max_examples=40, deadline=None)
@given(cam=cameras())
def test_opencv_opengl_round_trip(cam):
    gl = cam.c2w_opengl()
    np.testing.assert_array_equal(Camera.c2w_from_opengl(gl), cam.c2w)
    np.testing.assert_array_equal(gl[:3, 0], cam.c2w[:3, 0])
    np.testing.assert_array_equal(gl[:3, 1], -cam.c2w[:3, 1])  # GL y up = CV -y
    np.testing.assert_array_equal(gl[:3, 2], -cam.c2w[:3, 2])  # GL looks down -z
    np.testing.assert_array_equal(gl[:3, 3], cam.c2w[:3, 3])
    np.testing.assert_array_equal(CV_TO_GL @ CV_TO_GL, np.eye(4))


@settings(max_examples=60, deadline=None)
@given(cam=cameras(), u=st.floats(0, 1), v=st.floats(0, 1), z=st.floats(0.2, 50))
def test_projection_opengl_agrees_with_K(cam, u, v, z):
    near, far = 0.1, 100.0
    uv = np.array([[u * cam.width, v * cam.height]])
    X = cam.backproject(uv, np.array([z]))[0]
    eye = np.linalg.inv(cam.c2w_opengl()) @ np.append(X, 1.0)
    clip = cam.projection_opengl(near, far) @ eye
    ndc = clip[:3] / clip[3]
    np.testing.assert_allclose(ndc[0], 2.0 * uv[0, 0] / cam.width - 1.0, atol=1e-8)
    np.testing.assert_allclose(ndc[1], 1.0 - 2.0 * uv[0, 1] / cam.height, atol=1e-8)
    # depth maps monotonically into [-1, 1] between near and far
    expected = (far + near) / (far - near) - 2.0 * far * near / ((far - near) * z)
    np.testing.assert_allclose(ndc[2], expected, atol=1e-9)


def test_projection_opengl_near_far_planes():
    cam = simple_camera()
    P = cam.projection_opengl(0.5, 20.0)
    for z, ndc_z in ((0.5, -1.0), (20.0, 1.0)):
        clip = P @ np.array([0.0, 0.0, -z, 1.0])
        assert clip[2] / clip[3] == pytest.approx(ndc_z)


def test_look_at_basics():
    cam = Camera.look_at([0.0, 0.0, -5.0], [0.0, 0.0, 0.0], up=(0.0, 1.0, 0.0), width=64, height=48)
    np.testing.assert_allclose(cam.forward, [0, 0, 1], atol=1e-12)
    uv, _ = cam.project(np.array([[0.0, 0.0, 0.0]]))
    np.testing.assert_allclose(uv[0], [32.0, 24.0])  # the target lands at the image centre
    np.testing.assert_allclose(cam.R.T @ cam.R, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(cam.R), 1.0)
    with pytest.raises(InputError, match="coincide"):
        Camera.look_at([1, 2, 3], [1, 2, 3])
    with pytest.raises(InputError, match="parallel"):
        Camera.look_at([0, 0, 0], [0, 1, 0], up=(0, 1, 0))


def test_look_at_up_appears_up():
    # Standing at z = -5, facing +z with +y up, the viewer's right is world -x.
    cam = Camera.look_at([0.0, 0.0, -5.0], [0.0, 0.0, 0.0], up=(0.0, 1.0, 0.0), width=64, height=48)
    uv, _ = cam.project(np.array([[0.0, 0.0, 0.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]]))
    assert uv[1, 1] < uv[0, 1]  # world up is higher in the image (smaller v)
    assert uv[2, 0] > uv[0, 0]  # the viewer's right is to the right (larger u)
    np.testing.assert_allclose(-cam.c2w[:3, 1], [0.0, 1.0, 0.0], atol=1e-12)  # image-up (-y) = world up


def test_dict_round_trip_and_bad_input():
    cam = Camera.look_at([1.0, 2.0, 3.0], [0.0, 0.5, 0.0], width=33, height=17, name="x")
    back = Camera.from_dict(cam.to_dict())
    np.testing.assert_array_equal(back.K, cam.K)
    np.testing.assert_array_equal(back.c2w, cam.c2w)
    assert (back.width, back.height, back.name) == (33, 17, "x")
    with pytest.raises(InputError, match="non-finite"):
        Camera(np.eye(3), np.full((4, 4), np.nan), 4, 4)
    with pytest.raises(InputError, match="focal"):
        Camera(np.diag([0.0, 1.0, 1.0]), np.eye(4), 4, 4)
    with pytest.raises(InputError, match="size"):
        Camera(np.eye(3), np.eye(4), 0, 4)


def test_fov_and_rig_extent():
    cam = Camera(Camera.intrinsics_from_fov(np.radians(60.0), 100, 50), np.eye(4), 100, 50)
    assert np.degrees(cam.fov_y) == pytest.approx(60.0)
    rig = [cam.with_pose(np.block([[np.eye(3), np.array([[x], [0.0], [0.0]])], [np.zeros((1, 3)), np.ones((1, 1))]]))
           for x in (-1.0, 1.0)]
    assert rig_extent(rig) == pytest.approx(1.0)
    assert rig_extent([cam]) == pytest.approx(1e-6)
