"""Every threshold of geometric initialization, with the reason it has its value."""
from __future__ import annotations

# ---- poses (SfM) ------------------------------------------------------------------------
# A registration with fewer 3D points than this is too weak to trust for the rig's poses
# (COLMAP's own default min_model_size is 10; 4 views of a textured scene give hundreds).
SFM_MIN_POINTS = 20
# Fewer verified inlier matches than this between all view pairs together means SIFT found
# (almost) nothing in common: mapping would fail or be degenerate, so we stop early with advice.
SFM_MIN_INLIER_MATCHES = 30
# The similarity alignment (Umeyama) between estimated and given centres needs 3 non-collinear
# cameras; below this spread (relative to the rig radius) the rotation is ill-defined.
ALIGN_MIN_SPREAD = 1e-6

# ---- sparse baseline --------------------------------------------------------------------
# COLMAP's SIFT default keeps up to 8192 features; the 4-view sparse baseline keeps the default
# so that it is the usual COLMAP cloud the paper compares against.
SIFT_MAX_FEATURES = 8192
# COLMAP threads for SIFT, matching, triangulation and SfM. COLMAP's RANSAC draws from a
# thread-local generator that worker threads seed from the clock, so with more than one thread
# the sparse cloud changes from run to run (measured on the demo, frame 0: 98 or 97 points on
# three calls with all cores; 98, 98, 98 with one thread and a fixed seed). Reproducible reports
# matter more than the ~1 s a second thread saves per frame on four small views.
COLMAP_THREADS = 1
# Seed of COLMAP's generator on the calling thread (set on entry to every ColmapWorkspace).
COLMAP_SEED = 0

# ---- plane-sweep MVS ----------------------------------------------------------------------
# Hypotheses are uniform in inverse depth (disparity-like), the standard for plane sweeps:
# equal image-space steps at every depth.
MVS_DEFAULT_PLANES = 128
# Window side (pixels) of the ZNCC patch: 7x7 is the usual compromise between texture
# discrimination and edge fattening.
MVS_DEFAULT_WINDOW = 7
# Mean of the best-k source views per plane: robust to a source that is occluded at the pixel.
MVS_DEFAULT_TOPK = 2
# Box side of cost aggregation over the ZNCC volume (1 disables it); 3 smooths without
# re-blurring edges much (the ZNCC window already aggregates).
MVS_DEFAULT_AGGREGATION = 3
# Planes per chunk of the sweep: bounds memory to chunk x V x H x W floats.
MVS_DEFAULT_CHUNK = 16
# Coarse-to-fine sweep (cost: coarse_scale^3 + (2 band + 1) / planes of a full sweep, ~18% at
# 128 planes). The coarse level sweeps planes x coarse_scale planes (the full grid's step in
# pixels; a quarter of the planes aliased: only 75% of the full sweep's good depths had a coarse
# depth within 3 planes, demo static medians) at half resolution with a 3x3 window (a 7x7 one
# spans 14 full-resolution pixels and blurs thin and small structures: 92% within 3 planes with
# 7x7, 96% with 3x3, 3x3 median filter of the coarse map applied). The fine level then tests
# REFINE_BAND planes on each side of it.
MVS_COARSE_SCALE = 0.5
MVS_COARSE_WINDOW = 3
MVS_REFINE_BAND = 3
# Median filter (pixels, odd) of the coarse inverse-depth map before it is upsampled into the
# fine level's hypothesis surfaces. A fine ZNCC window sees its pixels' own hypotheses, so a
# noisy centre surface blurs the peak and the depth inherits the noise; a median keeps edges.
# Demo static medians, after the consistency check: coverage 0.387 with 3x3, 0.409 with 5x5
# (<1%: 0.665 -> 0.696; a 5x5 box instead loses edges: coverage 0.435 before the check vs 0.498).
MVS_COARSE_MEDIAN = 5
# Fine level of the coarse-to-fine sweep: tiles of this many pixels (inner side) sweep the
# planes their pixels need, each with a margin of ZNCC window + aggregation (so every score is
# the full sweep's): 16 px + 2 x 4 px margin = 2.25x the pixels, a tile's planes are the union
# of its pixels' bands.
MVS_TILE_PX = 16
# A pixel whose best coarse score is below this has no match at full resolution either: its
# planes are not swept (Panoptic static medians: 2.2% of the full sweep's valid pixels have a
# coarse best < 0.2, and 47% of the textured pixels; demo: 0.0% and 20%).
MVS_COARSE_MIN_SCORE = 0.2
# At most this many planes per tile (a tile spanning a large depth jump or noisy coarse depths
# keeps the planes most of its pixels need). Static medians, share of the full sweep's valid
# depths kept / sweep CPU s: demo 0.979 / 0.83 at 32, 0.971 / 0.79 at 24, 0.965 / 0.78 at 20;
# Panoptic 0.948 / 1.66, 0.945 / 1.44, 0.935 / 1.39.
MVS_TILE_MAX_PLANES = 24
# A pixel whose reference patch has an intensity std below this (on [0, 1]) has no texture:
# ZNCC is undefined there, so it is invalid (1/255 quantization noise is ~0.003).
MVS_MIN_PATCH_STD = 0.01
# ZNCC regularizer under the square root (variance units): avoids 0/0 on flat patches.
MVS_ZNCC_EPS = 1e-6
# Minimum aggregated ZNCC at the winning plane for a valid depth: below ~0.5 the match is
# usually occlusion, repetition or noise (COLMAP's PatchMatch uses a similar NCC bound).
MVS_MIN_SCORE = 0.5
# Minimum peak distinctiveness: winning score minus the mean score over all planes. A flat
# cost curve (ambiguous match) has a small gap.
MVS_MIN_DISTINCT = 0.15
# A warped patch with more than this share of its pixels outside the source image is unusable.
MVS_MIN_INSIDE = 0.9
# Geometric (left-right) consistency: forward-backward reprojection error (pixels) and relative
# depth disagreement below which two views agree (MVSNet/COLMAP use ~1 px and 1%).
MVS_GEO_PIXEL_TOL = 1.0
MVS_GEO_DEPTH_TOL = 0.01
# Views that must confirm a depth for it to stay valid after the consistency check.
MVS_GEO_MIN_VIEWS = 1
# Fallback depth range when neither SfM points nor a common view exist: around the point where
# the optical axes converge, from a third to three times its distance.
MVS_DEFAULT_RANGE_FACTOR = 3.0
# Forward-facing rigs with no common view: scene depth from 1x to 100x the rig radius
# (axes closer to parallel than fixer4d.geometry.rig.PARALLEL_AXES_SIN do not converge).
MVS_PARALLEL_NEAR_EXTENT = 1.0
MVS_PARALLEL_FAR_EXTENT = 100.0
# Depth range from SfM points: percentiles of the points' depths, widened by this factor on
# each side (points do not reach the scene's nearest and farthest surfaces).
MVS_POINTS_PERCENTILES = (1.0, 99.0)
MVS_POINTS_MARGIN = 1.25

# ---- fusion (Eq. 2) ----------------------------------------------------------------------
# Other views that must agree with a pixel's depth for its point to survive (paper: k).
FUSION_MIN_VIEWS = 1
# Relative depth tolerance of that agreement |z_proj - D_s| / D_s.
FUSION_DEPTH_TOL = 0.01
# Voxel size of the down-sampling, relative to the median depth of the fused points
# (0.002 ~ one pixel footprint at 640 px width and a 60 degree field of view).
FUSION_VOXEL_REL = 0.002
# Statistical outlier removal (open3d's definition): neighbours considered and the std-dev ratio beyond
# which a point is dropped (Open3D tutorial values).
FUSION_OUTLIER_NEIGHBORS = 20
FUSION_OUTLIER_STD = 2.0

# ---- quality against ground truth -----------------------------------------------------------
# Completeness tolerance, relative to the median ground-truth depth (scene scale): a true
# surface sample is covered when a cloud point lies within 1% of the viewing distance.
QUALITY_COMPLETENESS_REL = 0.01
# Surface samples kept for the quality metrics (random subset, fixed seed): enough for a
# stable share, bounded k-d tree cost.
QUALITY_MAX_SURFACE_SAMPLES = 200_000
# Relative depth bands reported for MVS depth maps.
QUALITY_DEPTH_BANDS = (0.01, 0.05)

# ---- moving-content masks (static rig, temporal statistics; init/masks.py) ---------------
# Robust noise scale: 1.4826 x MAD estimates the standard deviation of Gaussian noise.
MASK_MAD_TO_SIGMA = 1.4826
# A pixel moves when its deviation from its temporal median exceeds this many noise sigmas
# (the image's own noise level, from the MAD of every pixel's deviation: most pixels are
# static, so the median deviation is noise). 4 sigma keeps false alarms under ~1e-4 of pixels.
MASK_NOISE_K = 4.0
# Floor of that threshold (RGB in [0, 1]): a noise-free render has sigma ~ 0, and 8/255 is
# above JPEG/compression ringing while far below the contrast of real moving content.
MASK_MIN_DIFF = 0.03
# Seeds need a deviation this many times the threshold (hysteresis): a region is moving when
# it contains a strong change, and it then grows through pixels above the threshold itself.
MASK_SEED_FACTOR = 2.0
# A pixel whose median deviation over the clip exceeds this share of the threshold changes in
# most frames (an object spinning in place: its temporal median is no background), so it is
# moving in every frame. Half the threshold: at least half the frames differ clearly.
MASK_PERSIST_FACTOR = 0.5
# Connected regions smaller than this share of the image are dropped (specks of noise); 0.0002
# is ~12 pixels at 320x180, ~6 at 200x150.
MASK_MIN_AREA_FRAC = 0.0002
# Final dilation radius (pixels): a moving object's soft edge and motion blur reach about one
# pixel past where the difference test fires.
MASK_DILATE_PX = 1
# Frames of the clip the temporal statistics use at most (evenly spaced, plus the requested
# frames): a median over 32 samples is already stable; more only costs decode time.
MASK_STAT_FRAMES_MAX = 32
# Frames below which the statistics are too weak (a median of 2 is a mean): more frames are
# sampled from the clip to reach it.
MASK_STAT_FRAMES_MIN = 8
# Scene-provided foreground segmentation (Panoptic seg/) is moving in a frame when at least
# this share of a foreground region's pixels also moves by the temporal test: a person who
# stands still stays static, a walking one gets the segmentation's full, crisp silhouette.
MASK_SEG_MOVING_SHARE = 0.05
# The per-frame exposure gain (median ratio to the background) reads every 4th pixel of every
# 4th row: a median over thousands of pixels instead of all of them (the same masks up to a
# few pixels; mask time on Panoptic 320x180, 30 frames: the gains were ~25% of it).
MASK_GAIN_STRIDE = 4
# Rows of the image processed at once for the temporal median (bounds the F x rows x W x 3
# working copy to a few tens of MB at 640 px wide).
MASK_ROW_CHUNK = 64
