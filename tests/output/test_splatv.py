"""splaTV's .splatv: written by fixer4d, decoded by a reader of the byte layout written here."""
from __future__ import annotations

import json
import math
import struct

import numpy as np

from fixer4d.model.formats import splatv
from fixer4d.model.io import save_ply
from fixer4d.model.spacetime import ModelConfig
from output_scene import front_camera, small_model


def decode_splatv(data: bytes) -> tuple[list[dict], np.ndarray]:
    """The layout as splaTV's viewer reads it: uint32 magic 0x674b, uint32 JSON length, a JSON list
    of chunks, then the chunks' bytes; the 'splat' chunk is 16 uint32 words per Gaussian."""
    magic, length = struct.unpack_from("<II", data, 0)
    assert magic == 0x674B
    chunks = json.loads(data[8:8 + length].decode("utf-8"))
    offset = 8 + length
    for chunk in chunks:
        if chunk["type"] == "splat":
            words = np.frombuffer(data, dtype="<u4", count=chunk["size"] // 4, offset=offset)
            assert offset + chunk["size"] == len(data)
            return chunks, words.reshape(-1, 16)
        offset += chunk["size"]
    raise AssertionError("no splat chunk")


def halves(word: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The two float16 values of a packHalf2x16 word: the first in the low 16 bits."""
    lo = (word & 0xFFFF).astype(np.uint16).view(np.float16).astype(np.float32)
    hi = (word >> 16).astype(np.uint16).view(np.float16).astype(np.float32)
    return lo, hi


def test_written_file_decodes_field_by_field(tmp_path):
    model = small_model(1500, seed=3)  # > 1024 Gaussians: the texture has more than one row
    cams = [front_camera(), front_camera(name="side", azimuth_deg=60.0)]
    fields = splatv.reduce(model)
    path = splatv.write_splatv(fields, tmp_path / "m.splatv", cams)
    chunks, words = decode_splatv(path.read_bytes())
    chunk = chunks[0]
    n = len(fields)
    assert chunk["texwidth"] == 4096 and chunk["texheight"] == math.ceil(4 * n / 4096) == 2
    assert words.shape[0] == chunk["texwidth"] * chunk["texheight"] // 4 and not words[n:].any()
    cam = chunk["cameras"][1]
    assert cam["img_name"] == "side" and cam["width"] == 64 and cam["height"] == 48
    np.testing.assert_allclose(cam["position"], cams[1].center)
    np.testing.assert_allclose(np.array(cam["rotation"]), cams[1].R)  # camera-to-world rows
    assert cam["fx"] == cams[1].fx and cam["fy"] == cams[1].fy
    w = words[:n]
    np.testing.assert_array_equal(w[:, 0:3].copy().view("<f4"), fields.positions)
    rot = np.stack([*halves(w[:, 3]), *halves(w[:, 4])], 1)
    np.testing.assert_array_equal(rot, fields.rotations)
    sx, sy = halves(w[:, 5])
    sz, pad = halves(w[:, 6])
    np.testing.assert_array_equal(np.stack([sx, sy, sz], 1), fields.scales)
    assert not pad.any()
    rgba = np.stack([(w[:, 7] >> s) & 0xFF for s in (0, 8, 16, 24)], 1).astype(np.uint8)
    np.testing.assert_array_equal(rgba, fields.rgba)
    motion = np.stack([*halves(w[:, 8]), *halves(w[:, 9]), *halves(w[:, 10]), *halves(w[:, 11]), halves(w[:, 12])[0]], 1)
    np.testing.assert_array_equal(motion, fields.motion)
    np.testing.assert_array_equal(np.stack([*halves(w[:, 13]), *halves(w[:, 14])], 1), fields.omega)
    tc, ts = halves(w[:, 15])
    np.testing.assert_array_equal(tc, fields.t_center)
    np.testing.assert_array_equal(ts, fields.t_std)

    # and the stored values are the model's, in the stored order, to float16 / 8-bit precision
    src = fields.order
    dyn = model.dynamic.numpy()[src]
    np.testing.assert_array_equal(fields.positions, model.means.detach().numpy()[src])
    q = model.quats.detach().numpy()[src].astype(np.float64)
    qn = q / np.linalg.norm(q, axis=1, keepdims=True)
    np.testing.assert_allclose(rot, qn, atol=1e-3)
    np.testing.assert_allclose(np.log(fields.scales), model.log_scales.detach().numpy()[src], atol=1e-3)
    opacity = 1 / (1 + np.exp(-model.opacity_logits.detach().numpy()[src].astype(np.float64)))
    assert np.abs(fields.rgba[:, 3] / 255.0 - opacity).max() <= 0.5 / 255 + 1e-9
    rgb = np.clip(0.5 + 0.28209479177387814 * model.colors.detach().numpy()[src], 0, 1)
    assert np.abs(fields.rgba[:, :3] / 255.0 - rgb).max() <= 0.5 / 255 + 1e-6
    np.testing.assert_allclose(motion[dyn], model.motion.detach().numpy()[src][dyn], rtol=1e-3, atol=1e-4)
    assert not motion[~dyn].any() and not fields.omega[~dyn].any()  # static rows do not move
    np.testing.assert_allclose(np.log(ts[dyn]), model.t_log_scale.detach().numpy()[src][dyn], atol=1e-3)
    assert np.all(ts[~dyn] == splatv.STATIC_TEMPORAL_STD)
    np.testing.assert_allclose(tc[dyn], model.t_center.detach().numpy()[src][dyn], atol=1e-3)
    importance = np.exp(model.log_scales.detach().numpy()[src].astype(np.float64).sum(1)) * opacity
    assert np.all(np.diff(importance) <= 0)  # most important (volume x opacity) first

    back, cameras = splatv.read_splatv(path)
    assert len(back) == n and cameras == chunk["cameras"]
    np.testing.assert_array_equal(back.motion, fields.motion)


def test_export_verb_reports_the_reduction_error(tmp_path, capsys):
    from fixer4d.cli import main

    model = small_model(300, config=ModelConfig(sh_degree=0))  # nothing view-dependent to lose
    save_ply(model, tmp_path / "m.ply")
    assert main(["export", str(tmp_path / "m.ply"), "--out", str(tmp_path / "m.splatv")]) == 0
    assert "reduction error: PSNR" in capsys.readouterr().out
    report = json.loads((tmp_path / "m.splatv.json").read_text())
    assert len(report["samples"]) == 5 and report["gaussians"] == len(splatv.reduce(model))
    # 8-bit colour/opacity and float16 fields only: a small loss
    assert report["psnr_min"] >= 35.0, report["psnr_min"]
    with_sh = small_model(300, sh_scale=0.4)
    save_ply(with_sh, tmp_path / "sh.ply")
    assert main(["export", str(tmp_path / "sh.ply"), "--out", str(tmp_path / "sh.splatv")]) == 0
    lossy = json.loads((tmp_path / "sh.splatv.json").read_text())
    assert lossy["psnr_mean"] < report["psnr_mean"]  # view-dependent colour is what the format drops
