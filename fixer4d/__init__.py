"""fixer4d: four synchronized cameras -> spacetime Gaussians, with the unseen views repaired.

Importing fixer4d never imports optional backends (gsplat, diffusers, MVSAnywhere, GL); they
are loaded lazily where used.
"""
import os
import sys
from pathlib import Path

# Portable numerics (fixer4d/numerics.py): every library's CPU code path pinned so that a run gives
# the same digits on any x86-64 host; the libraries read the pins when they load, so this comes
# before anything imports torch, numpy or numba.
from fixer4d import numerics as _numerics  # noqa: E402

_numerics.apply()

# numba's parallel kernels and torch share one OpenMP runtime. With the default (active) wait
# policy, idle OpenMP workers spin after every parallel region and starve the next torch op on
# a 2-core machine: measured 137 ms vs 15 ms for one 200x150 render + loss. OpenMP reads this
# once, when the runtime loads, so it must be set before torch is imported.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
# numba ships its OpenMP pool on Linux; naming it keeps numba on the same OpenMP runtime as
# torch (and the wait policy above) and skips its probe of whatever TBB a venv may hold (an
# older one gave a warning on every run).
if sys.platform.startswith("linux"):
    os.environ.setdefault("NUMBA_THREADING_LAYER", "omp")
# Under a cgroup CPU quota smaller than the affinity mask (containers, CI runners) the pools
# would start a thread per host CPU; sized to the quota instead (fixer4d/cpus.py). The
# environment's own values win.
from fixer4d.cpus import thread_env_defaults  # noqa: E402

for _key, _value in thread_env_defaults().items():
    os.environ.setdefault(_key, _value)

__version__ = "0.1.0"

#: Repository root when run from a checkout (assets/ and shaders/ live there).
PACKAGE_ROOT = Path(__file__).resolve().parent
ASSETS_DIR = PACKAGE_ROOT.parent / "assets"
