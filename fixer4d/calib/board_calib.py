"""A rig from a ChArUco board filmed through the volume: per-camera lenses, then the poses that
tie the cameras together, in the board's metres.

1. Corners: the board's corners in up to ``BOARD_FRAMES`` frames spread over the board capture,
   the same frame numbers in every camera (the cameras are synchronized).
2. Lens (each camera alone): cv2.calibrateCamera on the frames where it sees the board: focal
   (square pixels), principal point and the distortion terms its views support (``fit_lens``);
   misdetected corners are dropped. A camera with too few views, or whose views leave the focal
   uncertain (an untilted or small board), is refused.
3. Poses: every frame seen by two cameras gives their relative pose (from each camera's board
   pose); the pairs with the most shared frames chain every camera to camera 0 (rotations
   averaged over the shared frames). Then one least-squares fit (``bundle_adjust``) of every
   lens, camera pose and board pose minimises the reprojection error of all corners: a board
   pose seen by several cameras ties their lenses and poses together.

The world is camera 0's axes with the origin at the mean camera centre, in metres. A camera that
never sees the board at the same instant as a camera linked to the others is refused, in one
InputError with each camera's board views and each pair's shared frames.
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from itertools import combinations
from typing import TYPE_CHECKING

import numpy as np
from tqdm import tqdm

from fixer4d.calib.board import MIN_VIEW_CORNERS, BoardSpec, CornerDetector
from fixer4d.calib.gate import MAX_REPROJECTION_PX, field_of_view_problems
from fixer4d.calib.rig import Rig, RigCamera, distort_points
from fixer4d.calib.sfm import spread_frames
from fixer4d.errors import InputError

if TYPE_CHECKING:  # calib reads a capture's frames through the object it is given; scene imports calib
    from fixer4d.scene.capture import CaptureFiles

# Frames sampled per camera: a board waved for a minute at 30 fps shows ~60 distinct poses once
# spread over the clip; calibrateCamera stays well under a second per camera with that many views.
BOARD_FRAMES = 60
# Views a lens fit needs: the focal and principal point (3 unknowns with square pixels) take two
# views at different tilts each plus one to spare; k1 then needs no more.
MIN_LENS_VIEWS = 4
# Views from which k2 is fitted too (radial distortion beyond the first term), and from which
# tangential distortion p1, p2 and a free principal point are: below these counts a planar board
# does not separate them from the focal and the board poses.
RADIAL2_VIEWS = 6
FULL_LENS_VIEWS = 12
# A corner farther from the first lens fit than this many times the median corner residual is a
# misdetection (measured on exact renders: boards seen more than ~50 degrees from square give 1 %
# of corners 0.7-3 px off while the median is 0.06 px), not noise: it is dropped.
OUTLIER_MEDIANS = 5.0
# Largest relative standard deviation of the focal (calibrateCamera's estimate) that is
# accepted: a board held square to the camera in every view leaves the focal free (it trades
# against the distance), which shows here before it shows in the reprojection error.
MAX_FOCAL_STD_REL = 0.01
# Robust loss scale of the joint fit (pixels): a ChArUco corner is good to ~0.1 px; a corner
# more than a pixel off (motion blur, a misread marker) is down-weighted rather than trusted.
JOINT_LOSS_PX = 1.0
# The lens parameters of the joint fit (OpenCV's pixel convention; square pixels).
LENS_TERMS = ("f", "cx", "cy", "k1", "k2", "p1", "p2")
BOARD_ADVICE = ("move the board slowly through the whole volume, tilted up to about 45 degrees towards and away "
                "from the cameras and into the corners of each image, where at least two cameras see it at once; "
                "film it at the cameras' full resolution, large enough that each marker spans about 25 px or more; "
                "check that the board spec (squares, sizes, dictionary) is the printed one and that the board "
                "videos are synchronized (--offset)")


@dataclass
class BoardViews:
    """frames: the board capture's frame numbers looked at; corners[c][k]: camera c's detection
    (ids (N,), uv (N, 2) pixels, OpenCV's convention) in frames[k], absent when not seen."""

    frames: list[int]
    corners: list[dict[int, tuple[np.ndarray, np.ndarray]]]


@dataclass
class Lens:
    """One camera's lens from its own board views. params: (7,) ``LENS_TERMS`` in OpenCV's pixel
    convention; free: (7,) which of them the views support; board_poses: view index -> (4, 4)
    board -> camera; views: the detections kept (view index -> (ids, uv)); rms_px: calibrateCamera's
    RMS reprojection error; focal_std_rel: the focal's standard deviation / focal."""

    params: np.ndarray
    free: np.ndarray
    board_poses: dict[int, np.ndarray]
    views: dict[int, tuple[np.ndarray, np.ndarray]]
    rms_px: float
    focal_std_rel: float

    @property
    def model(self) -> str:
        return ", ".join(t for t, f in zip(LENS_TERMS, self.free) if f)

    def camera(self, name: str, width: int, height: int, params: np.ndarray | None = None,
               w2c: np.ndarray | None = None) -> RigCamera:
        """A RigCamera with these (or the given) lens parameters, still in OpenCV's pixel convention."""
        f, cx, cy, k1, k2, p1, p2 = self.params if params is None else params
        return RigCamera(name, width, height, [[f, 0, cx], [0, f, cy], [0, 0, 1]], np.eye(4) if w2c is None else w2c,
                         {"k1": k1, "k2": k2, "p1": p1, "p2": p2})


def detect_views(files: CaptureFiles, spec: BoardSpec, cams: list[int], max_frames: int = BOARD_FRAMES,
                 progress: bool = True) -> BoardViews:
    """Board corners of cameras ``cams`` at up to ``max_frames`` frames spread over ``files``."""
    import cv2

    frames = spread_frames(files.num_frames, max_frames)
    detector = CornerDetector(spec)
    corners: list[dict] = [{} for _ in cams]
    bar = tqdm(total=len(frames) * len(cams), desc="calibrate: board corners", unit="frame", disable=not progress)
    for k, f in enumerate(frames):
        for i, c in enumerate(cams):
            found = detector.detect(cv2.cvtColor(files.frame(f, c), cv2.COLOR_RGB2GRAY))
            if found is not None:
                corners[i][k] = found
            bar.update(1)
    bar.close()
    return BoardViews([files.start + f for f in frames], corners)


def lens_flags(views: int) -> int:
    """cv2.calibrateCamera flags for a camera seen in ``views`` board views (before dropping terms)."""
    import cv2

    flags = cv2.CALIB_FIX_ASPECT_RATIO | cv2.CALIB_FIX_K3
    if views < FULL_LENS_VIEWS:
        flags |= cv2.CALIB_ZERO_TANGENT_DIST
    if views < RADIAL2_VIEWS:
        flags |= cv2.CALIB_FIX_K2 | cv2.CALIB_FIX_PRINCIPAL_POINT
    return flags


def _free_terms(flags: int) -> np.ndarray:
    import cv2

    return np.array([True, not flags & cv2.CALIB_FIX_PRINCIPAL_POINT, not flags & cv2.CALIB_FIX_PRINCIPAL_POINT,
                     not flags & cv2.CALIB_FIX_K1, not flags & cv2.CALIB_FIX_K2,
                     not flags & cv2.CALIB_ZERO_TANGENT_DIST, not flags & cv2.CALIB_ZERO_TANGENT_DIST])


def _calibrate(obj: list[np.ndarray], img: list[np.ndarray], size: tuple[int, int], flags: int):
    """cv2.calibrateCameraExtended with square pixels from scratch: (rms, K, coefficients (>= 5,),
    rvecs, tvecs, standard deviations of the intrinsics)."""
    import cv2

    # With CALIB_FIX_ASPECT_RATIO and no intrinsic guess only the ratio fx/fy of this matrix is
    # used; a fixed principal point stays at OpenCV's image centre.
    K0 = np.array([[1.0, 0.0, (size[0] - 1) / 2], [0.0, 1.0, (size[1] - 1) / 2], [0.0, 0.0, 1.0]])
    criteria = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 100, 1e-12)
    rms, K, dist, rvecs, tvecs, std, _, _ = cv2.calibrateCameraExtended(obj, img, size, K0, None, flags=flags,
                                                                         criteria=criteria)
    return rms, K, dist.ravel(), rvecs, tvecs, std.ravel()


def fit_lens(spec: BoardSpec, views: dict[int, tuple[np.ndarray, np.ndarray]], width: int, height: int) -> Lens:
    """A camera's lens from its board views (at least ``MIN_LENS_VIEWS``): cv2.calibrateCamera
    with the terms ``lens_flags`` allows; corners farther than ``OUTLIER_MEDIANS`` median
    residuals from that fit are dropped (with views left under ``MIN_VIEW_CORNERS`` or on one
    line); then each distortion term (tangential, k2, then k1) is dropped unless it lowers the
    Bayesian information criterion n ln(RSS / n) + k ln n over the n corner coordinates: a term
    the views cannot tell from none only adds noise to the focal and principal point (a per-term
    significance test misjudges the tangential terms, which trade against the principal point).
    ``Lens.views`` holds the views kept."""
    import cv2

    board = spec.corners()
    size = (width, height)
    flags = lens_flags(len(views))

    def arrays(v):
        keys = sorted(v)
        return (keys, [board[v[k][0]].astype(np.float32).reshape(-1, 1, 3) for k in keys],
                [v[k][1].astype(np.float32).reshape(-1, 1, 2) for k in keys])

    keys, obj, img = arrays(views)
    _, K, d, rvecs, tvecs, _ = _calibrate(obj, img, size, flags)
    residual = [np.linalg.norm(cv2.projectPoints(o, r, t, K, d)[0] - i, axis=-1).ravel()
                for o, i, r, t in zip(obj, img, rvecs, tvecs)]
    limit = OUTLIER_MEDIANS * float(np.median(np.concatenate(residual)))
    kept = {k: (views[k][0][e <= limit], views[k][1][e <= limit]) for k, e in zip(keys, residual)}
    collinear = spec.cv_board().checkCharucoCornersCollinear
    kept = {k: v for k, v in kept.items() if len(v[0]) >= MIN_VIEW_CORNERS and not collinear(v[0])}
    keys, obj, img = arrays(kept)
    n = 2 * sum(len(o) for o in obj)
    best = _calibrate(obj, img, size, flags)
    for term, needs in ((cv2.CALIB_ZERO_TANGENT_DIST, 0), (cv2.CALIB_FIX_K2, 0), (cv2.CALIB_FIX_K1, cv2.CALIB_FIX_K2)):
        if flags & term or (flags & needs) != needs:
            continue
        trial = _calibrate(obj, img, size, flags | term)
        fewer = int(_free_terms(flags).sum() - _free_terms(flags | term).sum())
        if n * np.log(max(trial[0], 1e-12) ** 2 / max(best[0], 1e-12) ** 2) < fewer * np.log(n):  # BIC does not rise
            flags, best = flags | term, trial
    rms, K, d, rvecs, tvecs, sd = best
    poses = {k: _to_matrix(cv2.Rodrigues(r)[0], t.reshape(3)) for k, r, t in zip(keys, rvecs, tvecs)}
    params = np.array([K[0, 0], K[0, 2], K[1, 2], *d[:4]])
    return Lens(params, _free_terms(flags), poses, kept, float(rms), float(np.max(sd[:2])) / float(K[1, 1]))


def _to_matrix(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    return T


def shared_frames(views: BoardViews) -> dict[tuple[int, int], list[int]]:
    """(a, b) -> the view indices both cameras see the board in."""
    return {(a, b): sorted(set(views.corners[a]) & set(views.corners[b]))
            for a, b in combinations(range(len(views.corners)), 2)}


def chain_to_reference(lenses: list[Lens], shared: dict[tuple[int, int], list[int]]) -> list[np.ndarray | None]:
    """Each camera's pose relative to camera 0 ((4, 4) camera-0 -> camera c), through a maximum
    spanning tree of the shared-frame counts (rotations averaged over a link's shared frames);
    None for cameras the tree cannot reach."""
    from scipy.spatial.transform import Rotation

    poses: list[np.ndarray | None] = [None] * len(lenses)
    poses[0] = np.eye(4)
    while True:
        best = None
        for (a, b), ks in shared.items():
            for p, c in ((a, b), (b, a)):
                if poses[p] is not None and poses[c] is None and ks and (best is None or len(ks) > len(best[2])):
                    best = (p, c, ks)
        if best is None:
            return poses
        p, c, ks = best
        rel = [lenses[c].board_poses[k] @ np.linalg.inv(lenses[p].board_poses[k]) for k in ks]
        c_from_p = _to_matrix(Rotation.from_matrix([r[:3, :3] for r in rel]).mean().as_matrix(),
                              np.mean([r[:3, 3] for r in rel], 0))
        poses[c] = c_from_p @ poses[p]


@dataclass
class _Observations:
    """Every detected corner: camera index, board-pose slot, board point, pixel."""

    cam: np.ndarray     # (M,)
    slot: np.ndarray    # (M,) index into the fitted board poses
    points: np.ndarray  # (M, 3) board metres
    uv: np.ndarray      # (M, 2) pixels (OpenCV's convention)


def _observations(spec: BoardSpec, views: BoardViews) -> tuple[_Observations, list[int]]:
    """All corners, and the view index of each board-pose slot."""
    board = spec.corners()
    keys = sorted(set().union(*views.corners))
    cam, slot, points, uv = [], [], [], []
    for s, k in enumerate(keys):
        for c, per_cam in enumerate(views.corners):
            if k in per_cam:
                ids, xy = per_cam[k]
                cam.append(np.full(len(ids), c))
                slot.append(np.full(len(ids), s))
                points.append(board[ids])
                uv.append(xy)
    return _Observations(np.concatenate(cam), np.concatenate(slot), np.concatenate(points), np.concatenate(uv)), keys


def bundle_adjust(lenses: list[Lens], sizes: list[tuple[int, int]], camera_poses: list[np.ndarray],
                  obs: _Observations, keys: list[int]) -> tuple[np.ndarray, list[np.ndarray], np.ndarray]:
    """One least-squares fit of every lens's free terms, the poses of cameras 1..V-1 (camera 0
    fixed: the gauge) and the board pose in every frame, over all corners. Returns the lens
    parameters (V, 7), the camera-0 -> camera poses and each corner's reprojection error (M,) px."""
    from scipy.optimize import least_squares
    from scipy.sparse import coo_matrix
    from scipy.spatial.transform import Rotation

    V = len(lenses)
    free = np.stack([lens.free for lens in lenses])  # (V, 7)
    lens_cols = np.cumsum(free.ravel()).reshape(V, 7) - 1  # column of each free term
    n_lens = int(free.sum())
    board0 = []
    for k in keys:  # the board pose from the first camera that sees it, in camera 0's frame
        c = next(c for c in range(V) if k in lenses[c].board_poses)
        board0.append(np.linalg.inv(camera_poses[c]) @ lenses[c].board_poses[k])

    def pack(T):
        return np.concatenate([Rotation.from_matrix(T[:3, :3]).as_rotvec(), T[:3, 3]])

    params0 = np.stack([lens.params for lens in lenses])
    x0 = np.concatenate([params0[free]] + [pack(T) for T in camera_poses[1:]] + [pack(T) for T in board0])

    def unpack(x):
        params = params0.copy()
        params[free] = x[:n_lens]
        p = x[n_lens:].reshape(-1, 6)
        return params, Rotation.from_rotvec(p[:, :3]).as_matrix(), p[:, 3:]

    def residuals(x):
        params, R, t = unpack(x)
        Rc = np.concatenate([np.eye(3)[None], R[:V - 1]])
        tc = np.concatenate([np.zeros((1, 3)), t[:V - 1]])
        Rb, tb = R[V - 1:], t[V - 1:]
        Xw = np.einsum("mij,mj->mi", Rb[obs.slot], obs.points) + tb[obs.slot]
        Xc = np.einsum("mij,mj->mi", Rc[obs.cam], Xw) + tc[obs.cam]
        out = np.empty_like(obs.uv)
        for c in range(V):
            m = obs.cam == c
            cam = lenses[c].camera("", *sizes[c], params[c])
            out[m] = distort_points(cam, Xc[m, :2] / Xc[m, 2:] * params[c, 0] + params[c, 1:3]) - obs.uv[m]
        return out.ravel()

    rows = np.arange(2 * len(obs.cam))
    cam_of_row, slot_of_row = obs.cam[rows // 2], obs.slot[rows // 2]
    r, col = [], []
    for c in range(V):  # lens terms
        for j in np.flatnonzero(free[c]):
            r.append(rows[cam_of_row == c])
            col.append(np.full(int(np.sum(cam_of_row == c)), lens_cols[c, j]))
    moving = cam_of_row > 0
    r += [np.repeat(rows[moving], 6), np.repeat(rows, 6)]
    col += [(n_lens + 6 * (cam_of_row[moving] - 1)[:, None] + np.arange(6)).ravel(),
            (n_lens + 6 * (V - 1 + slot_of_row)[:, None] + np.arange(6)).ravel()]
    r, col = np.concatenate(r), np.concatenate(col)
    sparsity = coo_matrix((np.ones(len(r), np.int8), (r, col)), shape=(len(rows), len(x0)))
    fit = least_squares(residuals, x0, jac_sparsity=sparsity, x_scale="jac", loss="soft_l1", f_scale=JOINT_LOSS_PX,
                        method="trf")
    params, R, t = unpack(fit.x)
    poses = [np.eye(4)] + [_to_matrix(R[i], t[i]) for i in range(V - 1)]
    return params, poses, np.linalg.norm(fit.fun.reshape(-1, 2), axis=1)


def _refuse(label: str, found: list[str], names: list[str], views: BoardViews,
            shared: dict[tuple[int, int], list[int]]) -> InputError:
    seen = ", ".join(f"{n} {len(views.corners[i])}" for i, n in enumerate(names))
    together = ", ".join(f"{names[a]}-{names[b]} {len(ks)}" for (a, b), ks in shared.items())
    return InputError(f"{label}: board calibration refused: {'; '.join(found)}. Frames with the board (of "
                      f"{len(views.frames)} looked at): {seen}; seen together: {together}. To fix: {BOARD_ADVICE}")


def board_pair_table(rig: Rig) -> str:
    """'cam00-cam01 25 frames, 480 corners; ...' for a board rig's pairs."""
    return "; ".join(f"{p['cameras'][0]}-{p['cameras'][1]} {p['shared_frames']} frames, {p['shared_corners']} corners"
                     for p in rig.pairs)


def calibrate_board(files: CaptureFiles, spec: BoardSpec, names: list[str] | None = None, *,
                    max_frames: int = BOARD_FRAMES, progress: bool = True) -> Rig:
    """The rig of cameras ``names`` (default: all of ``files``) from the board frames in ``files``.

    Raises InputError (one line: the problem per camera, the views, what to do) when a camera is
    missing from the board capture, sees the board too rarely, never together with the others, or
    the fit is not trustworthy (reprojection error, focal uncertainty, field of view).
    """
    import cv2

    t0 = time.perf_counter()
    label = str(files.root)
    names = list(names or files.names)
    missing = [n for n in names if n not in files.names]
    if missing:
        raise InputError(f"{label}: no board video for cameras {missing} (it has {files.names}); film the board "
                         f"with every camera and name each video or image folder after its camera")
    if len(names) < 2:
        raise InputError(f"{label}: calibration needs at least 2 cameras, found {names}")
    cams = [files.names.index(n) for n in names]
    views = detect_views(files, spec, cams, max_frames, progress)
    shared = shared_frames(views)
    few = [f"camera {n} sees the board in {len(views.corners[i])} frames (a lens needs >= {MIN_LENS_VIEWS})"
           for i, n in enumerate(names) if len(views.corners[i]) < MIN_LENS_VIEWS]
    if few:
        raise _refuse(label, few, names, views, shared)
    sizes = [(files.sources[c].width, files.sources[c].height) for c in cams]
    lenses = []
    for i, n in enumerate(names):
        try:
            lenses.append(fit_lens(spec, views.corners[i], *sizes[i]))
        except cv2.error as exc:  # e.g. no view whose corners span a plane
            raise _refuse(label, [f"camera {n}'s lens fit failed ({exc.err})"], names, views, shared) from None
    views.corners = [lens.views for lens in lenses]
    shared = shared_frames(views)
    camera_poses = chain_to_reference(lenses, shared)
    alone = [n for n, p in zip(names, camera_poses) if p is None]
    if alone:
        raise _refuse(label, [f"camera {n} never sees the board at the same instant as {names[0]} or a camera linked "
                              f"to it" for n in alone], names, views, shared)
    obs, keys = _observations(spec, views)
    params, camera_poses, errors = bundle_adjust(lenses, sizes, camera_poses, obs, keys)
    centres = np.stack([np.linalg.inv(T)[:3, 3] for T in camera_poses])
    mean = centres.mean(0)
    cameras = []
    for i, (n, T) in enumerate(zip(names, camera_poses)):
        w2c = T.copy()
        w2c[:3, 3] = -T[:3, :3] @ (centres[i] - mean)
        cam = lenses[i].camera(n, *sizes[i], params[i], w2c)
        cam.K[:2, 2] += 0.5  # rig.json's pixel centres sit at +0.5 (the inverse of rig.opencv_K)
        cam.reprojection_error_px = float(np.mean(errors[obs.cam == i]))
        cameras.append(cam)
    found = [f"camera {c.name} has {c.reprojection_error_px:.2f} px mean reprojection error (at most "
             f"{MAX_REPROJECTION_PX} px)" for c in cameras if c.reprojection_error_px > MAX_REPROJECTION_PX]
    found += [f"camera {n}'s focal is uncertain to {lens.focal_std_rel:.1%} from {len(lens.views)} board views (at "
              f"most {MAX_FOCAL_STD_REL:.0%}: more views, tilted more, the board larger in the image)"
              for n, lens in zip(names, lenses) if lens.focal_std_rel > MAX_FOCAL_STD_REL]
    found += field_of_view_problems(cameras)
    if found:
        raise _refuse(label, found, names, views, shared)
    pairs = [{"cameras": [names[a], names[b]], "shared_frames": len(ks),
              "shared_corners": sum(len(np.intersect1d(views.corners[a][k][0], views.corners[b][k][0])) for k in ks)}
             for (a, b), ks in shared.items()]
    checks = {"board": spec.to_dict(), "frames_with_board": {n: len(views.corners[i]) for i, n in enumerate(names)},
              "lens_model": {n: lens.model for n, lens in zip(names, lenses)},
              "lens_rms_px": {n: round(lens.rms_px, 4) for n, lens in zip(names, lenses)},
              "focal_std_rel": {n: lens.focal_std_rel for n, lens in zip(names, lenses)},
              "seconds": round(time.perf_counter() - t0, 2)}
    return Rig(cameras, pairs, views.frames,
               f"metres (ChArUco squares of {spec.square_m} m): camera {names[0]}'s axes, origin at the mean camera "
               f"centre", f"ChArUco board ({spec.describe()}) in {len(views.frames)} frames of {label}", checks)
