"""Prints a JSON object {probe: sha1 of its bytes} for ops whose last bits follow the CPU code path
each library picks at run time (tests/numerics/test_portable_numerics.py runs it under emulated
hosts): ATen's vectorized exp and sums, MKL's matmul, oneDNN's convolution, OpenBLAS's matmul,
numpy's SIMD exp and sin, a numba ``reassoc`` reduction, OpenCV's area resize, and (where pycolmap
is installed) the sparse baseline's SIFT + triangulation on the demo's frame 0, whose OpenBLAS and
SIMD paths are pycolmap's own."""
import hashlib
import json

import fixer4d  # noqa: F401  (first: sets the numerics pins before the libraries load)

import cv2
import numpy as np
import torch

from fixer4d import numerics
from fixer4d.jit import njit

g = torch.Generator().manual_seed(0)
rng = np.random.default_rng(0)
x = torch.randn(100003, generator=g)
a, b = torch.randn(257, 129, generator=g), torch.randn(129, 263, generator=g)
image = torch.randn(1, 16, 33, 35, generator=g)
kernel = torch.randn(24, 16, 3, 3, generator=g)
an = rng.standard_normal((257, 129)).astype(np.float32)
v32 = rng.standard_normal(100003).astype(np.float32)


@njit(fastmath={"reassoc"})
def _sum(v):
    s = np.float32(0)
    for i in range(v.shape[0]):
        s += v[i] * np.float32(1.0001)
    return s


out = {
    "torch_exp": torch.exp(x).numpy(), "torch_sum": torch.sum(x * 1.1).numpy(), "torch_mm": (a @ b).numpy(),
    "torch_conv": torch.nn.functional.conv2d(image, kernel).numpy(),
    "numpy_mm": an @ an.T, "numpy_exp": np.exp(v32), "numpy_sin": np.sin(v32.astype(np.float64)),
    "numba_reassoc": np.float32(_sum(v32)),
    "opencv_resize": cv2.resize(rng.random((181, 243, 3), dtype=np.float32), (97, 61), interpolation=cv2.INTER_AREA),
}
try:
    import pycolmap  # noqa: F401
except ImportError:
    pass
else:
    from fixer4d.init.sparse import sparse_cloud
    from fixer4d.scene import load_scene

    scene = load_scene("demo")
    cloud, _ = sparse_cloud([scene.frame(0, i) for i in scene.train_ids], scene.train_cameras, 0, 0.0)
    out["pycolmap_sparse"] = np.concatenate([cloud.points, cloud.colors], axis=1)
print(json.dumps({"hashes": {k: hashlib.sha1(np.ascontiguousarray(v).tobytes()).hexdigest() for k, v in out.items()},
                  "portable": numerics.status()["portable"], "torch_threads": torch.get_num_threads()}))
