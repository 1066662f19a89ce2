"""render_video and `fixer4d render`: playable H.264 files and PNG folders, decoded back here."""
from __future__ import annotations

import av
import numpy as np
import pytest
from PIL import Image

from fixer4d.errors import InputError
from fixer4d.geometry.trajectory import Trajectory, save_nerfstudio
from fixer4d.model.io import save_ply
from fixer4d.render.video import RenderCancelled, model_frame_fn, render_video
from output_scene import front_camera, small_model


def decode(path) -> list[np.ndarray]:
    with av.open(str(path)) as container:
        stream = container.streams.video[0]
        assert stream.codec_context.name == "h264"
        return [f.to_ndarray(format="rgb24") for f in container.decode(stream)]


def test_mp4_and_png_frames_match_the_renders(tmp_path):
    model = small_model(200)
    cams = [front_camera(name=f"c{k}", azimuth_deg=10.0 * k) for k in range(6)]
    times = [k / 6 for k in range(6)]
    seen = []
    out = render_video(model, cams, times, tmp_path / "clip.mp4", fps=24.0, progress=lambda d, t: seen.append((d, t)))
    assert out == tmp_path / "clip.mp4" and seen == [(k, 6) for k in range(1, 7)]
    frames = decode(out)
    assert len(frames) == 6 and frames[0].shape == (48, 64, 3)
    with av.open(str(out)) as container:
        assert float(container.streams.video[0].average_rate) == 24.0
    fn = model_frame_fn(model)
    expected = np.round(np.clip(fn(cams[3], times[3]), 0, 1) * 255)
    assert np.abs(frames[3].astype(float) - expected).mean() < 6.0  # lossy H.264 of the same image
    pngs = render_video(model, cams, times, tmp_path / "frames")
    names = sorted(p.name for p in pngs.iterdir())
    assert names == [f"frame_{k:05d}.png" for k in range(6)]
    np.testing.assert_array_equal(np.asarray(Image.open(pngs / names[3])), expected.astype(np.uint8))
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_odd_sizes_cancel_and_bad_input(tmp_path):
    model = small_model(50)
    odd = [front_camera(width=33, height=25)] * 2
    assert decode(render_video(model, odd, [0.0, 0.5], tmp_path / "odd.mp4"))[0].shape == (26, 34, 3)
    calls = []

    def stop_after_two():
        calls.append(1)
        return len(calls) > 2

    for out in (tmp_path / "cancel.mp4", tmp_path / "cancel_frames"):
        calls.clear()
        with pytest.raises(RenderCancelled, match="after 2 of 5"):
            render_video(model, [front_camera()] * 5, [0.0] * 5, out, should_stop=stop_after_two)
        assert not out.exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # the partial output is gone
    with pytest.raises(InputError, match="2 cameras but 1 times"):
        render_video(model, odd, [0.0], tmp_path / "x.mp4")
    with pytest.raises(InputError, match="one size"):
        render_video(model, [front_camera(), front_camera(width=32)], [0.0, 0.0], tmp_path / "x.mp4")
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "keep.txt").write_text("x")
    with pytest.raises(InputError, match="holds other files"):
        render_video(model, odd, [0.0, 0.5], tmp_path / "mine")


def _run_folder(tmp_path, model):
    from fixer4d.pipeline.config import resolve
    from fixer4d.pipeline.run_folder import RunFolder

    run = RunFolder.create(tmp_path / "run", resolve("tiny")).path
    save_ply(model, run / "model_stage1.ply")
    return run


def test_render_verb_with_a_camera_path_rig_cameras_and_trajectories(tmp_path, capsys):
    from fixer4d.cli import main

    run = _run_folder(tmp_path, small_model(150))
    cams = [front_camera(width=80, height=60, name=f"p{k}", azimuth_deg=8.0 * k) for k in range(5)]
    path = save_nerfstudio(Trajectory("orbit", cams, np.linspace(0, 1, 5), times=np.linspace(0, 0.8, 5)),
                           tmp_path / "camera_path.json", fps=10.0)
    assert main(["render", str(run), "--camera-path", str(path), "--out", str(tmp_path / "v.mp4"), "--quiet"]) == 0
    frames = decode(tmp_path / "v.mp4")
    assert len(frames) == 5 and frames[0].shape == (60, 80, 3)
    with av.open(str(tmp_path / "v.mp4")) as container:
        assert float(container.streams.video[0].average_rate) == 10.0  # the camera path's fps
    # a rig camera of the run's scene (tiny: 8 cameras, 4 frames at 64x48), next to its recording
    assert main(["render", str(run), "--camera", "cam01", "--side-by-side", "--out", str(tmp_path / "sbs"),
                 "--quiet"]) == 0
    pngs = sorted((tmp_path / "sbs").iterdir())
    assert len(pngs) == 4 and np.asarray(Image.open(pngs[0])).shape == (48, 128, 3)
    assert main(["render", str(run), "--trajectory", "0-1", "--frames", "3", "--out", str(tmp_path / "t.mp4"),
                 "--quiet"]) == 0
    assert len(decode(tmp_path / "t.mp4")) == 3
    capsys.readouterr()
    assert main(["render", str(run), "--trajectory", "9-9", "--out", str(tmp_path / "n.mp4"), "--quiet"]) == 2
    assert "no such trajectory" in capsys.readouterr().err
    assert main(["render", str(run / "model_stage1.ply"), "--camera", "0", "--out", str(tmp_path / "n.mp4")]) == 2
    assert "bare model file" in capsys.readouterr().err
    assert main(["render", str(run), "--camera-path", str(path), "--side-by-side", "--out", str(tmp_path / "n.mp4")]) == 2
    assert not (tmp_path / "n.mp4").exists()
