"""Save and load SpacetimeGaussians as STGS-style PLY or as npz; both round trips are exact.

PLY: binary little-endian, one ``vertex`` element with the STGS lite field names
x, y, z, trbf_center, trbf_scale, motion_0..8, omega_0..3, f_dc_0..2, [f_rest_*], opacity,
scale_0..2, rot_0..3, a uint8 ``dynamic`` field and, when the model has frozen rows (another
segment's shared static Gaussians), a uint8 ``frozen`` field. Every STGS field is always written, so other
STGS tools load any fixer4d model: terms the model does not have are written as their neutral
values (zero motion/omega, t_center 0 and a temporal log-scale of ``NEUTRAL_TRBF_SCALE``). The
model config travels in a ``comment fixer4d {...}`` header line; a PLY without it is another
tool's and is read by ``fixer4d.model.formats.foreign`` (STGS lite, 3DGS, or a refusal naming its
fields). f_rest is channel-major (f_rest_{c*K + k}) as 3DGS writes it.

npz: one array per Parameter (native dtype), ``dynamic``, ``frozen``, and the config as JSON.
Loading validates: non-finite values raise NumericalError naming the file and the field.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import torch

from fixer4d.atomic import atomic_path
from fixer4d.errors import InputError
from fixer4d.model.spacetime import MAX_MOTION_DEGREE, ModelConfig, SpacetimeGaussians

FORMAT = "fixer4d-stgs"
VERSION = 1
_COMMENT_TAG = "fixer4d "

# Written as trbf_scale when the model has no temporal opacity: exp(-(dt / e^20)^2) = 1 to float
# precision for any dt in the clip, so a reader that applies the STGS RBF sees constant opacity.
NEUTRAL_TRBF_SCALE = 20.0

_MOTION_FIELDS = [f"motion_{i}" for i in range(3 * MAX_MOTION_DEGREE)]
_OMEGA_FIELDS = [f"omega_{i}" for i in range(4)]


def _ply_fields(num_sh_rest: int) -> list[str]:
    return (["x", "y", "z", "trbf_center", "trbf_scale", *_MOTION_FIELDS, *_OMEGA_FIELDS,
             "f_dc_0", "f_dc_1", "f_dc_2", *[f"f_rest_{i}" for i in range(3 * num_sh_rest)],
             "opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"])


def _np(t: torch.Tensor) -> np.ndarray:
    return t.detach().cpu().numpy()


def save_ply(model: SpacetimeGaussians, path: str | Path) -> Path:
    """Write ``model`` to ``path`` (binary little-endian PLY, float32 fields), atomically."""
    from plyfile import PlyData, PlyElement

    model.check(str(path))
    cfg = model.config
    n = model.num_gaussians
    k = cfg.num_sh_rest
    cols: dict[str, np.ndarray] = {}
    means = _np(model.means)
    cols["x"], cols["y"], cols["z"] = means[:, 0], means[:, 1], means[:, 2]
    cols["trbf_center"] = _np(model.t_center) if cfg.has_time_terms else np.zeros(n)
    cols["trbf_scale"] = _np(model.t_log_scale) if cfg.temporal_opacity else np.full(n, NEUTRAL_TRBF_SCALE)
    motion = np.zeros((n, 3 * MAX_MOTION_DEGREE))
    if cfg.motion_degree > 0:
        motion[:, : 3 * cfg.motion_degree] = _np(model.motion)
    omega = _np(model.omega) if cfg.rotation_velocity else np.zeros((n, 4))
    for i, f in enumerate(_MOTION_FIELDS):
        cols[f] = motion[:, i]
    for i, f in enumerate(_OMEGA_FIELDS):
        cols[f] = omega[:, i]
    dc = _np(model.colors)
    for c in range(3):
        cols[f"f_dc_{c}"] = dc[:, c]
    if k:
        rest = _np(model.sh_rest).transpose(0, 2, 1).reshape(n, 3 * k)  # channel-major
        for i in range(3 * k):
            cols[f"f_rest_{i}"] = rest[:, i]
    cols["opacity"] = _np(model.opacity_logits)
    ls, q = _np(model.log_scales), _np(model.quats)
    for i in range(3):
        cols[f"scale_{i}"] = ls[:, i]
    for i in range(4):
        cols[f"rot_{i}"] = q[:, i]
    names = _ply_fields(k)
    frozen = _np(model.frozen).astype(np.uint8)
    flags = [("dynamic", "u1")] + ([("frozen", "u1")] if frozen.any() else [])
    data = np.empty(n, dtype=[(f, "<f4") for f in names] + flags)
    for f in names:
        data[f] = cols[f]
    data["dynamic"] = _np(model.dynamic).astype(np.uint8)
    if frozen.any():
        data["frozen"] = frozen
    header = json.dumps({"format": FORMAT, "version": VERSION, "config": cfg.to_dict()}, separators=(",", ":"))
    ply = PlyData([PlyElement.describe(data, "vertex")], text=False, byte_order="<",
                  comments=[_COMMENT_TAG + header])
    with atomic_path(path) as tmp:
        ply.write(str(tmp))
    return Path(path)


def _config_from_ply(comments: list[str], path: Path) -> ModelConfig | None:
    """The config in a fixer4d header comment, or None when the PLY has none (another tool's)."""
    for c in comments:
        if c.startswith(_COMMENT_TAG):
            try:
                meta = json.loads(c[len(_COMMENT_TAG):])
            except json.JSONDecodeError as exc:
                raise InputError(f"{path}: unreadable fixer4d header comment ({exc}); re-export the model") from exc
            return _config_from_header(meta, path)
    return None


def load_ply(path: str | Path) -> SpacetimeGaussians:
    """Read a PLY written by ``save_ply`` (or an STGS lite / 3DGS PLY, ``formats.foreign``) into a float32 model."""
    from plyfile import PlyData

    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such model file; pass a .ply/.npz written by fixer4d or a run folder")
    try:
        ply = PlyData.read(str(path))
        v = ply["vertex"].data
    except Exception as exc:  # plyfile raises several types for truncated/corrupt files
        raise InputError(f"{path}: not a readable PLY with a 'vertex' element ({exc}); re-export the model") from exc
    names = set(v.dtype.names or ())
    cfg = _config_from_ply(list(ply.comments), path)
    if cfg is None:
        from fixer4d.model.formats.foreign import read_foreign_ply

        return read_foreign_ply(v, path)
    required = ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", *[f"scale_{i}" for i in range(3)],
                *[f"rot_{i}" for i in range(4)]]
    if cfg.has_time_terms:
        required.append("trbf_center")
    if cfg.temporal_opacity:
        required.append("trbf_scale")
    required += _MOTION_FIELDS[: 3 * cfg.motion_degree] + (_OMEGA_FIELDS if cfg.rotation_velocity else [])
    required += [f"f_rest_{i}" for i in range(3 * cfg.num_sh_rest)]
    missing = [f for f in required if f not in names]
    if missing:
        raise InputError(f"{path}: missing PLY fields {missing}")

    def stack(fields: list[str]) -> np.ndarray:
        return np.stack([np.asarray(v[f], dtype=np.float32) for f in fields], axis=1)

    n = len(v)
    k = cfg.num_sh_rest
    t: dict[str, np.ndarray] = {
        "means": stack(["x", "y", "z"]),
        "log_scales": stack([f"scale_{i}" for i in range(3)]),
        "quats": stack([f"rot_{i}" for i in range(4)]),
        "opacity_logits": np.asarray(v["opacity"], dtype=np.float32),
        "colors": stack(["f_dc_0", "f_dc_1", "f_dc_2"]),
    }
    if k:
        t["sh_rest"] = stack([f"f_rest_{i}" for i in range(3 * k)]).reshape(n, 3, k).transpose(0, 2, 1).copy()
    if cfg.has_time_terms:
        t["t_center"] = np.asarray(v["trbf_center"], dtype=np.float32)
    if cfg.temporal_opacity:
        t["t_log_scale"] = np.asarray(v["trbf_scale"], dtype=np.float32)
    if cfg.motion_degree:
        t["motion"] = stack(_MOTION_FIELDS[: 3 * cfg.motion_degree])
    if cfg.rotation_velocity:
        t["omega"] = stack(_OMEGA_FIELDS)
    for flag in ("dynamic", "frozen"):
        if flag in names:
            t[flag] = np.asarray(v[flag]) != 0
    return SpacetimeGaussians.from_tensors(cfg, t, source=str(path))


def save_npz(model: SpacetimeGaussians, path: str | Path) -> Path:
    """Write ``model`` to ``path`` (.npz, native dtypes, config as JSON), atomically."""
    model.check(str(path))
    arrays = {name: _np(tensor) for name, tensor in model.tensors().items()}
    arrays["format"] = np.array(json.dumps({"format": FORMAT, "version": VERSION,
                                            "config": model.config.to_dict()}))
    with atomic_path(path, suffix=".npz") as tmp:
        np.savez(tmp, **arrays)
    return Path(path)


def load_npz(path: str | Path) -> SpacetimeGaussians:
    """Read a model written by ``save_npz``."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such model file; pass a .ply/.npz written by fixer4d or a run folder")
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
    except Exception as exc:  # zipfile/ValueError/OSError for truncated or foreign files
        raise InputError(f"{path}: not a readable fixer4d .npz ({exc}); re-export the model") from exc
    if "format" not in arrays:
        raise InputError(f"{path}: no 'format' entry; this .npz was not written by fixer4d save_npz")
    try:
        meta = json.loads(str(arrays.pop("format")))
    except json.JSONDecodeError as exc:
        raise InputError(f"{path}: unreadable 'format' entry ({exc}); re-export the model") from None
    not_numeric = sorted(k for k, a in arrays.items() if a.dtype.kind not in "biuf")
    if not_numeric:
        raise InputError(f"{path}: entries {not_numeric} are not numeric arrays (dtype "
                         f"{arrays[not_numeric[0]].dtype}); a fixer4d .npz holds float and bool arrays: re-export it")
    return SpacetimeGaussians.from_tensors(_config_from_header(meta, path), arrays, source=str(path))


def _config_from_header(meta: object, path: Path) -> ModelConfig:
    """The ModelConfig of a fixer4d header ``{"format", "version", "config"}`` (PLY comment or npz
    entry); one InputError sentence for a foreign, newer or malformed header."""
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        found = meta.get("format") if isinstance(meta, dict) else type(meta).__name__
        raise InputError(f"{path}: header format {found!r} is not {FORMAT!r}; this file was not written by "
                         "fixer4d: re-export the model with fixer4d")
    version = meta.get("version")
    if not isinstance(version, int) or version > VERSION:
        raise InputError(f"{path}: model format version {version!r}, but this fixer4d reads versions <= {VERSION}; "
                         "update fixer4d")
    try:
        return ModelConfig.from_dict(meta["config"])
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(f"{path}: malformed model config in the header ({type(exc).__name__}: {exc}); "
                         "re-export the model") from None


def save_model(model: SpacetimeGaussians, path: str | Path) -> Path:
    """Save by extension: .ply or .npz."""
    suffix = Path(path).suffix.lower()
    if suffix == ".ply":
        return save_ply(model, path)
    if suffix == ".npz":
        return save_npz(model, path)
    raise InputError(f"{path}: unknown model format {suffix!r}; use .ply or .npz")


def load_model(path: str | Path) -> SpacetimeGaussians:
    """Load by extension: .ply or .npz."""
    suffix = Path(path).suffix.lower()
    if suffix == ".ply":
        return load_ply(path)
    if suffix == ".npz":
        return load_npz(path)
    raise InputError(f"{path}: unknown model format {suffix!r}; use .ply or .npz")
