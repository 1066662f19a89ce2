"""Every threshold of the Gaussian rasterizer, with its reason.

One constant set serves every backend, forward and backward (the reference oracle, the numba
kernel and, where gsplat exposes the knob, the CUDA backend), so that they render the same image
and differentiate the same function.
"""
from __future__ import annotations

# Added to the diagonal of every projected 2D covariance (pixels^2). EWA anti-aliasing (3DGS,
# gsplat's eps2d): it convolves each splat with a pixel-sized low-pass filter so that a Gaussian
# smaller than a pixel still covers about one pixel instead of aliasing or vanishing.
LOWPASS_2D = 0.3

# Smallest determinant (pixels^4) of a 2D covariance we invert. After the low-pass a valid
# covariance has det >= LOWPASS_2D**2 = 0.09, so anything below this is a numerically broken
# (non positive-definite) projection: the Gaussian is culled instead of inverted.
DET_MIN = 1e-6

# Splat extent in standard deviations: a pixel centre farther than 3 sigma (Mahalanobis) from
# the projected mean gets no contribution; the integer radius ceil(3 sqrt(lambda_max)) bounds it.
# Applied per pixel (not per tile, unlike 3DGS) so the image does not depend on the tiling.
SIGMA_EXTENT = 3.0
# The same cut in terms of the exponent: 0.5 * d^T conic d <= 0.5 * SIGMA_EXTENT^2.
POWER_MAX = 0.5 * SIGMA_EXTENT * SIGMA_EXTENT

# Near plane, in world units of camera-frame z (absolute, as gsplat's near_plane=0.01). Gaussians
# whose mean has z <= NEAR_PLANE are culled: the perspective Jacobian grows as 1/z^2 and is
# meaningless behind the camera. Absolute rather than relative to the scene because fixer4d's
# scenes are normalised to a rig of unit-order size, where 0.01 is well inside every camera's
# near bound and still far above float32 round-off of z.
NEAR_PLANE = 0.01

# Tangent clamp of the EWA Jacobian (3DGS/gsplat): the camera-frame x/z, y/z used in the Jacobian
# are clamped to the field of view widened by this fraction of tan(fov/2) on each side. A Gaussian
# far off-screen otherwise gets a huge, ill-conditioned 2D covariance that smears across the image.
TAN_FOV_MARGIN = 0.3

# Largest alpha of one splat: keeps 1 - alpha >= 0.01 so the backward pass can divide by it to
# recover the transmittance before a splat, and a single Gaussian never fully occludes.
ALPHA_MAX = 0.99

# Smallest alpha that is blended (1/255, one 8-bit level): fainter splats are skipped, which
# bounds the work per pixel and the footprint of nearly-transparent Gaussians.
ALPHA_MIN = 1.0 / 255.0

# Early termination: a pixel stops blending once the next splat would take its transmittance
# below this (3DGS's 0.0001); what remains behind is invisible at 8 bits.
T_MIN = 1e-4

# Tile edge in pixels for binning Gaussians to image regions (both CPU backends). Not a
# semantic constant: results do not depend on it because the extent test is per pixel.
TILE = 8
