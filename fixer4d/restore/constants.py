"""Every threshold the restorers use, with the reason next to it (docs/design.md §3).

The ``ReferenceWarpConfig`` defaults point at these, so a study can sweep them without
editing code.
"""
from __future__ import annotations

# ---- geometry -------------------------------------------------------------------------
# A rendered pixel whose accumulated opacity is at least this has a trustworthy expected
# depth (depth = sum(w z) / alpha); below it the depth is dominated by a few faint splats.
ALPHA_DEPTH_MIN = 0.5
# A reference pixel's model depth is trusted for the occlusion test when the model covers it
# this much (same reasoning as ALPHA_DEPTH_MIN, at the reference camera).
REF_ALPHA_MIN = 0.5
# Relative depth tolerance of the occlusion test: a warped point is visible in a reference if
# its depth there lies within this fraction of the reference's own depth (3x3 min..max range,
# so depth discontinuities and grazing surfaces are not rejected by one-pixel misalignment).
OCCLUSION_REL_TOL = 0.03
# Forward-splatted reference depth leaves one-pixel cracks where the novel view magnifies the
# reference; this many 3x3 min-filter passes close them without bridging real gaps.
SPLAT_CRACK_PASSES = 2

# ---- fusion ---------------------------------------------------------------------------
# Angular spread (radians) of the proximity weight exp(-angle / sigma) between the novel ray and
# a source ray through the same point: ~6 degrees, so the nearest visible view dominates (its warp
# suffers least from depth error and view dependence). Measured on the bench fixture over three
# pairs with exact and 2%-wrong depth: 0.10 -> 28.2 dB mean, 0.15 -> 28.2, 0.26 -> 27.9.
ANGLE_SIGMA_RAD = 0.1
# Photometric agreement scale (RGB in [0, 1], mean absolute difference over channels): two
# warps of the same surface differ by resampling noise (~0.02); 0.1 means they see different
# surfaces (a missed occlusion) or a view-dependent highlight.
AGREEMENT_SIGMA = 0.1
# Gaussian sigma (pixels) of the low-pass used to compare a warp with the (possibly blurred)
# render: wide enough that render blur does not count as disagreement.
LOWPASS_SIGMA_PX = 3.0
# Gaussian sigma (pixels) of the window over which local Laplacian energy is measured when
# deciding whether the render is blurrier than the warped references.
DETAIL_WINDOW_SIGMA_PX = 2.0
# Energies below this (squared Laplacian of [0, 1] images) are flat regions where neither image
# carries detail and the blur ratio is meaningless.
DETAIL_ENERGY_FLOOR = 1e-4
# Baseline trust in a visible, consistent warp of a real frame versus the render where the
# render is neither a hole nor blurry: real pixels are ground truth at that timestamp, but a
# warp through an imperfect model depth can be misaligned, so the render keeps some weight.
# Measured on the bench fixture (blurred render, exact / 2%-wrong depth): 0.5 -> 27.6 / 25.7 dB,
# 0.8 -> 28.7 / 26.1, 1.0 -> 29.5 / 26.4; 0.8 keeps a margin for renders sharper than the fixture's.
REF_BASE_TRUST = 0.8
# Alpha at which a render pixel counts as a hole (nothing rendered there); the hole weight is a
# smooth ramp from 0 at HOLE_ALPHA_HIGH to 1 at HOLE_ALPHA_LOW.
HOLE_ALPHA_LOW = 0.2
HOLE_ALPHA_HIGH = 0.8
# Weight multiplier for the extra real views relative to the two endpoint references (they are
# real frames of the same timestamp; the angular weight already favours whichever is nearest).
EXTRA_VIEW_WEIGHT = 1.0
# Whether the extra real views are used at all. Measured (bench fixture, 200x150, F=8, pairs
# 0-1, 1-2, 0-2, 0-3, exact and 2%-wrong depth, mean PSNR): with 29.3 dB, without 28.6 dB; pairs
# 0-2 and 0-3 gain 0.9-1.8 dB, adjacent pairs change by <= 0.1 dB. Extra views never decide the
# depth of a render hole where an endpoint reference has one (see reference_warp._novel_depth).
USE_EXTRA_VIEWS = True
# ---- inpainting and confidence --------------------------------------------------------
# Pixels whose known weight (render share where it is not a hole + warp share) is below this
# are blended toward the push-pull fill in proportion to what is missing; at 0 they are pure
# fill with confidence 0. 0.3 keeps thin, faint support (e.g. one grazing reference) mostly.
INPAINT_KNOWN_FULL = 0.3

# ---- temporal consistency -------------------------------------------------------------
# Frames on each side whose fusion weights (warped through the depth into the current frame)
# are averaged with its own. Measured (bench fixture, 128x96, F=12, mean |frame k - frame k+1
# warped into k|): exact depth 0.0094 -> 0.0085, 2%-wrong depth 0.0119 -> 0.0110 with radius 1,
# PSNR unchanged; radius 2 adds nothing.
TEMPORAL_RADIUS = 1
# Weight of each neighbour relative to the centre frame in that average.
TEMPORAL_NEIGHBOR_WEIGHT = 0.5

# ---- validation -----------------------------------------------------------------------
# Depth values are z-depths in world units; anything non-finite or <= this is "no depth".
MIN_VALID_DEPTH = 1e-6

# ---- learned restorer (restore/learned.py, train/restorer_pairs.py) --------------------
# Base channel width of the restorer CNN (a 3-level U-Net; ~62 k parameters at 16): wide enough
# to learn blend maps and a small residual from a few dozen pairs, small enough to train in
# about a minute of one CPU core; its inference costs about as much as the warp restorer itself.
LEARNED_WIDTH = 16
# The residual added after blending is bounded to +-this (tanh): it corrects colour shifts and
# blend seams; anything larger would be the network inventing content it cannot know.
LEARNED_RESIDUAL_BOUND = 0.1
# Logit bias of the "reference-warp output" candidate at initialization: the untrained network
# reproduces the warp restorer (softmax weight 0.83 at 3.0 over 5 candidates), so training
# starts from the geometric restorer and learns where to depart from it.
LEARNED_INIT_WARP_LOGIT = 3.0
# Per-pixel error (mean |restored - real| over channels) at which the confidence target is
# exp(-1): 0.05 ~ the colour noise of a well-reconstructed real view.
LEARNED_CONF_ERROR_SCALE = 0.05
# Weights of the loss terms: L1 + 0.2 D-SSIM (the STGS image loss) + 0.1 confidence BCE (the
# confidence head must not steer the colour output).
LEARNED_SSIM_WEIGHT = 0.2
LEARNED_CONF_WEIGHT = 0.1
# Per-channel colour correction of a warped reference onto the render (gain, bias by least
# squares over pixels visible in both): only where the render is solid, gains clamped to this
# range so that a wrong render cannot recolour a real image.
COLOR_FIT_ALPHA_MIN = 0.9
COLOR_GAIN_RANGE = (0.8, 1.25)
COLOR_BIAS_MAX = 0.1
# Fewer matched pixels than this: no colour correction (the fit would be noise).
COLOR_FIT_MIN_PIXELS = 64
