"""Where a plane sweep runs: the boxes around a view's regions of interest, the camera of a
crop, and the tiles of the coarse-to-fine sweep with the planes each tile sweeps."""
from __future__ import annotations

import numpy as np
import torch

from fixer4d.geometry.camera import Camera
import fixer4d.init.constants as C


def roi_boxes(mask: np.ndarray, margin: int) -> list[tuple[int, int, int, int]]:
    """Boxes (x0, y0, x1, y1) covering a region mask (H, W) bool: one per connected region of
    the mask widened by ``margin`` pixels (clipped to the image), boxes merged while a merge does
    not add pixels to sweep (union area <= the sum of both). Sorted; [] for an empty mask."""
    import cv2

    m = np.asarray(mask, bool).astype(np.uint8)
    if margin > 0:
        m = cv2.dilate(m, np.ones((2 * margin + 1, 2 * margin + 1), np.uint8))
    n, _, stats, _ = cv2.connectedComponentsWithStats(m, connectivity=8)
    boxes = [(int(x), int(y), int(x + w), int(y + h)) for x, y, w, h in stats[1:, :4]]

    def area(b):
        return (b[2] - b[0]) * (b[3] - b[1])

    merged = True
    while merged:
        merged = False
        for i in range(len(boxes)):
            for j in range(i + 1, len(boxes)):
                a, b = boxes[i], boxes[j]
                u = (min(a[0], b[0]), min(a[1], b[1]), max(a[2], b[2]), max(a[3], b[3]))
                if area(u) <= area(a) + area(b):
                    boxes[i] = u
                    del boxes[j]
                    merged = True
                    break
            if merged:
                break
    return sorted(boxes)


def crop_camera(cam: Camera, box: tuple[int, int, int, int]) -> Camera:
    """The camera of the sub-image ``box`` = (x0, y0, x1, y1) (principal point shifted)."""
    x0, y0, x1, y1 = box
    if (x0, y0, x1, y1) == (0, 0, cam.width, cam.height):
        return cam
    K = cam.K.copy()
    K[0, 2] -= x0
    K[1, 2] -= y0
    return Camera(K, cam.c2w, x1 - x0, y1 - y0, cam.name)


def tile_axis(n: int, size: int, margin: int) -> list[tuple[int, int, int]]:
    """Tiles of one image axis of length n: (start, end, padded start) with inner extent
    [start, end) of at most ``size`` and a padded extent of min(n, size + 2 margin) from the
    padded start, kept inside the image (at the image border the window shrinks as it does in
    a whole-image sweep; elsewhere the padding holds the margin)."""
    padded = size + 2 * margin
    if n <= padded:
        return [(0, n, 0)]
    return [(a, min(a + size, n), min(max(a - margin, 0), n - padded)) for a in range(0, n, size)]


def tile_planes(centre: torch.Tensor, band: int, P: int) -> torch.Tensor:
    """Sorted planes (long) a tile sweeps: every plane within ``band`` of one of its pixels'
    ``centre`` planes (-1 = a pixel that needs none), at most MVS_TILE_MAX_PLANES of them (then
    those serving the most pixels, ties to the nearer plane: a tile mixing many depths keeps its
    main surfaces)."""
    c = centre.reshape(-1)
    c = c[c >= 0]
    count = torch.zeros(P, dtype=torch.long)
    for off in range(-band, band + 1):
        count += torch.bincount((c + off).clamp(0, P - 1), minlength=P)
    planes = torch.nonzero(count).squeeze(1)
    if planes.numel() > C.MVS_TILE_MAX_PLANES:
        order = torch.argsort(count[planes], descending=True, stable=True)
        planes = planes[order[:C.MVS_TILE_MAX_PLANES]].sort().values
    return planes

