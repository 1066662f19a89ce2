"""The ray-caster against analytic answers."""
from __future__ import annotations

import numpy as np
import pytest

from fixer4d.geometry import quaternion
from fixer4d.geometry.camera import Camera
from fixer4d.scene import motion, raycast, shapes, textures
from fixer4d.scene.synthetic import SyntheticScene, look_at_c2w

SOLID = textures.Texture("solid", colors=np.array([[0.6, 0.3, 0.2], [0.6, 0.3, 0.2]]))
# Ambient 1, no directional term: every hit shows its albedo exactly.
FLAT_LIGHT = raycast.Light(np.array([0.0, 1.0, 0.0]), np.ones(3), 0.0, 1.0)
BG = np.array([0.0, 0.0, 1.0])


def world(*objects: raycast.SceneObject, light: raycast.Light = FLAT_LIGHT) -> raycast.World:
    return raycast.World(tuple(objects), light, BG)


def obj(shape: shapes.Shape, center, rotation=None, motions=(), texture=SOLID, specular=None) -> raycast.SceneObject:
    return raycast.SceneObject("o", shape, np.asarray(center, np.float64),
                               np.eye(3) if rotation is None else rotation, texture, specular, tuple(motions))


def random_camera(rng: np.random.Generator, width=64, height=48) -> Camera:
    eye = rng.uniform(-2, 2, 3)
    target = eye + rng.normal(size=3)
    c2w = look_at_c2w(eye, target, np.array([0.0, 1.0, 0.0]))
    K = np.array([[rng.uniform(40, 80), 0, rng.uniform(20, 44)], [0, rng.uniform(40, 80), rng.uniform(15, 33)], [0, 0, 1]])
    return Camera(K, c2w, width, height, "r")


def test_fronto_parallel_plane_depth_is_constant_for_any_pose():
    rng = np.random.default_rng(0)
    for _ in range(5):
        cam = random_camera(rng)
        D = rng.uniform(0.5, 20.0)
        # Plane through the point D along the optical axis, normal = the viewing direction.
        R = cam.R  # plane local z = camera forward, local x/y = camera x/y
        plane = obj(shapes.Shape("plane"), cam.center + D * cam.forward, rotation=R)
        rgb, depth = raycast.render(world(plane), cam, 0.0)
        np.testing.assert_allclose(depth, D, rtol=1e-6)
        np.testing.assert_allclose(rgb, np.broadcast_to(SOLID.colors[0], rgb.shape), atol=1e-6)


def test_oblique_plane_depth_matches_ray_parameter():
    cam = Camera(Camera.intrinsics_from_fov(np.radians(60), 40, 30), np.eye(4), 40, 30)
    n = np.array([0.0, -0.6, 0.8])
    p0 = np.array([0.0, 0.0, 4.0])
    R = np.stack([np.array([1.0, 0, 0]), np.cross(n, [1.0, 0, 0]), n], 1)
    _, depth = raycast.render(world(obj(shapes.Shape("plane"), p0, rotation=R)), cam, 0.0)
    d = cam.ray_directions()  # camera-frame z = 1, so the ray parameter is the z-depth
    expected = (p0 @ n) / (d @ n)
    expected = np.where(expected > 0, expected, np.inf)
    np.testing.assert_allclose(depth, expected, rtol=1e-6)


def test_known_point_lands_at_its_projection():
    """A small sphere centred at X is hit at pixel floor(camera.project(X)), at depth z - r."""
    rng = np.random.default_rng(1)
    r = 0.01
    hits = 0
    for _ in range(20):
        cam = random_camera(rng)
        X = cam.center + rng.uniform(2, 6) * cam.forward + rng.normal(scale=0.5, size=3)
        uv, z = cam.project(X[None])
        u, v = uv[0]
        if not (1 <= u < cam.width - 1 and 1 <= v < cam.height - 1):
            continue
        # Cast exactly the ray through the projection: it must hit the sphere's near pole.
        ray = np.linalg.inv(cam.K) @ np.array([u, v, 1.0])
        t = shapes.intersect_local(shapes.Shape("sphere", r), cam.center - X, (cam.R @ ray)[None])[0]
        assert abs(t - z[0]) < r * 1.01
        _, depth = raycast.render(world(obj(shapes.Shape("sphere", r), X)), cam, 0.0, supersample=1)
        ys, xs = np.nonzero(np.isfinite(depth))
        # The sphere's image (a disc of radius < 1 px here) covers pixel centres only near (u, v).
        assert np.all(np.abs(xs + 0.5 - u) < 1.0) and np.all(np.abs(ys + 0.5 - v) < 1.0)
        hits += 1
    assert hits >= 8


def test_pixel_centre_convention_of_rays():
    """A sphere centred on the ray through the centre of pixel (i, j) covers exactly that pixel."""
    cam = Camera(Camera.intrinsics_from_fov(np.radians(50), 32, 24), np.eye(4), 32, 24)
    i, j = 7, 19 - 4
    X = cam.backproject(np.array([[i + 0.5, j + 0.5]]), np.array([5.0]))[0]
    _, depth = raycast.render(world(obj(shapes.Shape("sphere", 0.02), X)), cam, 0.0)
    assert list(zip(*np.nonzero(np.isfinite(depth)))) == [(j, i)]
    ray = np.linalg.inv(cam.K) @ [i + 0.5, j + 0.5, 1.0]  # z = 1: the near pole is 0.02 / |ray| closer in z
    assert depth[j, i] == pytest.approx(5.0 - 0.02 / np.linalg.norm(ray), abs=1e-6)


def test_sphere_silhouette_radius():
    W, H, D, r = 96, 80, 6.0, 1.5
    cam = Camera(Camera.intrinsics_from_fov(np.radians(50), W, H), np.eye(4), W, H)
    _, depth = raycast.render(world(obj(shapes.Shape("sphere", r), [0.0, 0.0, D])), cam, 0.0)
    rho = cam.fx * r / np.sqrt(D * D - r * r)  # image radius of the tangent cone, centred sphere
    uv = cam.pixel_centers()
    dist = np.hypot(uv[..., 0] - cam.cx, uv[..., 1] - cam.cy)
    margin = 1e-3
    assert np.all(np.isfinite(depth[dist < rho - margin]))
    assert np.all(np.isinf(depth[dist > rho + margin]))
    assert depth[H // 2, W // 2] == pytest.approx(D - r, abs=1e-3)


def test_oriented_box_and_cylinder_depths():
    cam = Camera(Camera.intrinsics_from_fov(np.radians(40), 33, 33), np.eye(4), 33, 33)
    centre_ray = (16, 16)  # pixel whose centre is on the optical axis (cx = 16.5)
    half = np.array([0.5, 0.5, 0.5])
    _, d = raycast.render(world(obj(shapes.Shape("box", half=half), [0, 0, 5.0])), cam, 0.0)
    assert d[centre_ray] == pytest.approx(4.5, rel=1e-6)  # float32 output
    rot = quaternion.to_matrix(np.array([np.cos(np.pi / 8), 0.0, np.sin(np.pi / 8), 0.0]))  # 45 deg about y
    _, d = raycast.render(world(obj(shapes.Shape("box", half=half), [0, 0, 5.0], rotation=rot)), cam, 0.0)
    assert d[centre_ray] == pytest.approx(5.0 - 0.5 * np.sqrt(2), rel=1e-6)  # float32 output  # the edge faces the camera
    # Cylinder along y seen from the side: front of the curved surface at D - r.
    cyl = shapes.Shape("cylinder", radius=0.4, half=np.array([0.0, 1.0, 0.0]))
    _, d = raycast.render(world(obj(cyl, [0, 0, 5.0])), cam, 0.0)
    assert d[centre_ray] == pytest.approx(4.6, rel=1e-6)  # float32 output
    # Rotated 90 deg about x the axis points at the camera: the cap at D - h/2.
    rx = quaternion.to_matrix(np.array([np.cos(np.pi / 4), np.sin(np.pi / 4), 0.0, 0.0]))
    _, d = raycast.render(world(obj(cyl, [0, 0, 5.0], rotation=rx)), cam, 0.0)
    assert d[centre_ray] == pytest.approx(4.0, rel=1e-6)  # float32 output


def test_nearest_hit_wins_and_misses_are_inf_with_background():
    cam = Camera(Camera.intrinsics_from_fov(np.radians(40), 21, 21), np.eye(4), 21, 21)  # pixel 10 on the axis
    red = textures.Texture("solid", colors=np.array([[1.0, 0, 0], [1.0, 0, 0]]))
    front = obj(shapes.Shape("sphere", 0.3), [0, 0, 3.0], texture=red)
    back = obj(shapes.Shape("plane", half=np.array([0.5, 0.5])), [0, 0, 6.0])
    rgb, d = raycast.render(world(back, front), cam, 0.0)
    assert d[10, 10] == pytest.approx(2.7, rel=1e-6)  # float32 output
    np.testing.assert_allclose(rgb[10, 10], [1, 0, 0], atol=1e-6)
    assert np.isinf(d[0, 0]) and np.allclose(rgb[0, 0], BG)


def test_moving_object_at_two_times():
    spec = {
        "frames": 10, "fps": 10,
        "rig": {"layout": "arc", "count": 4, "radius": 5.0, "arc_deg": 10, "target": [0, 0, 0],
                "width": 64, "height": 48, "fov_y_deg": 50},
        "lighting": {"ambient": 1.0, "intensity": 0.0},
        "objects": [{"type": "sphere", "center": [0, 0, 0], "radius": 0.15, "texture": {"kind": "solid", "color": [1, 1, 1]},
                     "motion": {"kind": "path", "keys": [[0.0, -1.0, 0.0, 0.0], [1.0, 1.0, 0.5, 0.0]]}}],
    }
    scene = SyntheticScene(spec, supersample=1)
    cam = scene.cameras[1]
    for t, expected in ((0.0, [-1.0, 0.0, 0.0]), (0.5, [0.0, 0.25, 0.0])):  # 0.5 s into a 1 s linear path
        _, depth = scene.render_gt(cam, t)
        ys, xs = np.nonzero(np.isfinite(depth))
        uv, _ = cam.project(np.array([expected]))
        assert abs(xs.mean() + 0.5 - uv[0, 0]) < 0.5 and abs(ys.mean() + 0.5 - uv[0, 1]) < 0.5
    assert "motion" in scene.effects


def test_spin_and_bounce_poses():
    spin = motion.SpinMotion(np.array([0.0, 1.0, 0.0]), 90.0)
    c, R = motion.apply_motion(np.zeros(3), np.eye(3), (spin,), 1.0)
    np.testing.assert_allclose(R @ [1.0, 0, 0], [0, 0, -1.0], atol=1e-12)
    bounce = motion.BounceMotion(np.array([0.0, 1.0, 0.0]), 0.5, 2.0)
    c, _ = motion.apply_motion(np.array([1.0, 0, 0]), np.eye(3), (bounce,), 1.0)
    np.testing.assert_allclose(c, [1.0, 0.5, 0.0])
    path = motion.PathMotion(np.array([0.0, 1.0, 2.0]), np.array([[0.0, 0, 0], [1, 0, 0], [1, 1, 0]]), smooth=True)
    for s, p in ((0.0, [0, 0, 0]), (1.0, [1, 0, 0]), (2.0, [1, 1, 0]), (5.0, [1, 1, 0])):
        np.testing.assert_allclose(motion.path_position(path, s), p, atol=1e-12)


def test_supersampling_keeps_centre_depth_and_averages_colour():
    scene = SyntheticScene("tiny")
    cam = scene.cameras[0]
    rgb1, d1 = raycast.render(scene.world, cam, 0.05, supersample=1)
    for k in (2, 3):
        rgbk, dk = raycast.render(scene.world, cam, 0.05, supersample=k)
        np.testing.assert_array_equal(dk, d1)
        # Smooth regions agree with the centre sample; only edges change.
        assert np.median(np.abs(rgbk - rgb1)) < 0.02
    # A flat-coloured scene is identical at any supersampling.
    flat = world(obj(shapes.Shape("plane"), [0, 0, 5.0]))
    plain = Camera(Camera.intrinsics_from_fov(1.0, 16, 12), np.eye(4), 16, 12)
    np.testing.assert_allclose(raycast.render(flat, plain, 0.0, supersample=4)[0], raycast.render(flat, plain, 0.0)[0],
                               atol=1e-6)


def test_chunking_does_not_change_the_image():
    scene = SyntheticScene("tiny")
    a = raycast.render(scene.world, scene.cameras[2], 0.07, supersample=2)
    b = raycast.render(scene.world, scene.cameras[2], 0.07, supersample=2, chunk_rays=97)
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])


def test_textures_are_deterministic_and_in_range():
    rng = np.random.default_rng(3)
    p = rng.uniform(-5, 5, (1000, 3))
    for tex in (textures.Texture("checker", scale=2.0), textures.Texture("stripes", scale=3.0),
                textures.Texture("noise", scale=1.5, octaves=3, seed=7),
                textures.Texture("blend", a=textures.Texture("checker"), b=textures.Texture("noise"), weight=0.3)):
        a = textures.eval_texture(tex, p)
        assert a.shape == (1000, 3) and np.all((a >= 0) & (a <= 1))
        np.testing.assert_array_equal(a, textures.eval_texture(tex, p))
    n = textures.value_noise(p, 3, 0)
    assert n.std() > 0.05  # not flat
    # Continuous: nearby points have nearby values (anti-aliasable, unlike white noise).
    assert np.abs(textures.value_noise(p + 1e-4, 3, 0) - n).max() < 1e-2


def test_exact_moving_mask_is_the_moving_objects_first_hits(tiny_scene):
    """moving_mask = pixels whose first hit is the (only) moving object: where the ball alone
    would be hit, the pixel is moving exactly when nothing static lies in front of it."""
    import copy

    spec = copy.deepcopy(tiny_scene.spec)
    spec["objects"] = [o for o in spec["objects"] if o.get("motion")]
    ball_only = SyntheticScene(spec)
    seen = 0
    for f in range(tiny_scene.num_frames):
        for cam in (tiny_scene.train_ids[0], tiny_scene.test_ids[0]):
            mask = tiny_scene.moving_mask(f, cam)
            full, ball = tiny_scene.depth(f, cam), ball_only.depth(f, cam)
            hit = np.isfinite(ball)
            assert not (mask & ~hit).any()
            np.testing.assert_array_equal(mask, hit & (ball <= full))
            seen += int(mask.sum())
    assert seen > 0
