"""`bench train-step --opensplat`: the nerfstudio project writer, the runner and the "not run" path."""
from __future__ import annotations

import json
import stat
import sys

import numpy as np
import pytest
from PIL import Image

from fixer4d.bench import opensplat, train_step
from fixer4d.errors import InputError
from fixer4d.geometry.camera import Camera


def _cameras():
    return [Camera.look_at([3.0 * np.cos(a), 0.5, 3.0 * np.sin(a)], [0.0, 0.0, 0.0], fov_y=np.radians(50.0),
                           width=40 + 8 * i, height=24, name=f"c{i}") for i, a in enumerate((0.1, 1.3, 2.9))]


def _project(tmp_path):
    rng = np.random.default_rng(0)
    cams = _cameras()
    images = [rng.uniform(0, 1, (c.height, c.width, 3)).astype(np.float32) for c in cams]
    pts, cols = rng.uniform(-1, 1, (57, 3)), rng.uniform(0, 1, (57, 3))
    return cams, images, pts, cols, opensplat.write_nerfstudio_project(tmp_path / "proj", cams, images, pts, cols)


def test_project_files_are_valid_nerfstudio(tmp_path):
    from plyfile import PlyData

    cams, images, pts, cols, root = _project(tmp_path)
    meta = json.loads((root / "transforms.json").read_text())
    assert meta["camera_model"] == "OPENCV" and (root / meta["ply_file_path"]).is_file()
    frames = meta["frames"]
    # OpenSplat sorts frames by file name: that order must be the cameras' order
    assert [f["file_path"] for f in frames] == sorted(f["file_path"] for f in frames)
    for f, cam, img in zip(frames, cams, images):
        assert (f["w"], f["h"]) == (cam.width, cam.height)
        assert np.allclose([f["fl_x"], f["fl_y"], f["cx"], f["cy"]], [cam.fx, cam.fy, cam.cx, cam.cy])
        c2w = np.array(f["transform_matrix"])
        assert c2w.shape == (4, 4) and np.allclose(c2w[3], [0, 0, 0, 1])
        # nerfstudio/OpenGL axes: the camera looks down its -z, y up; centre unchanged
        assert np.allclose(c2w[:3, 3], cam.center)
        assert np.allclose(-c2w[:3, 2], cam.forward)
        assert np.allclose(c2w[:3, 1], -cam.R[:, 1])
        png = np.asarray(Image.open(root / f["file_path"]))
        assert png.shape == (cam.height, cam.width, 3) and png.dtype == np.uint8
        assert np.abs(png / 255.0 - img).max() <= 0.5 / 255 + 1e-6
    ply = PlyData.read(str(root / "points.ply"))
    v = ply["vertex"]
    assert v.count == len(pts)
    assert np.allclose(np.stack([v["x"], v["y"], v["z"]], 1), pts, atol=1e-6)
    assert np.array_equal(np.stack([v["red"], v["green"], v["blue"]], 1), np.round(cols * 255).astype(np.uint8))


def test_project_rejects_mismatched_images(tmp_path):
    cams = _cameras()
    with pytest.raises(InputError, match="image 0"):
        opensplat.write_nerfstudio_project(tmp_path, cams, [np.zeros((3, 3, 3))] * 3, np.zeros((1, 3)), np.zeros((1, 3)))


# What a stand-in binary answers to --version / --help: OpenSplat up to 1.1.x, and 1.2.0
_OLD_CLI = """if args in (["--version"], ["--help"]):
    print("1.1.5" if args == ["--version"] else "  --warmup-length arg  Split/duplicate/prune gaussians only after")
    raise SystemExit(0)"""
_NEW_CLI = """if args in (["--version"], ["--help"]):
    print("1.2.0" if args == ["--version"] else "  --densify-from arg\\n  --densify-until arg")
    raise SystemExit(0)"""


def _stand_in(path, body: str, cli: str = _OLD_CLI):
    path.write_text(f"#!{sys.executable}\nimport sys\nargs = sys.argv[1:]\n{cli}\n{body}\n")
    path.chmod(path.stat().st_mode | stat.S_IXUSR)
    return path


def test_refinement_is_held_off_by_each_version_own_option(tmp_path):
    old = _stand_in(tmp_path / "os11", "raise SystemExit(0)")
    new = _stand_in(tmp_path / "os12", "raise SystemExit(0)", _NEW_CLI)
    assert opensplat.opensplat_info(old) == {"version": "1.1.5", "refine": "warmup-length"}
    assert opensplat.opensplat_info(new) == {"version": "1.2.0", "refine": "densify-from"}
    cmd = opensplat.opensplat_command("os", tmp_path, 60, tmp_path / "o.ply", refine="densify-from")
    # 1.2.0 steps Adam every iteration only up to densify-until: both past the run
    assert cmd[cmd.index("--densify-from") + 1] == cmd[cmd.index("--densify-until") + 1] == "70"
    assert "--warmup-length" not in cmd
    cmd = opensplat.opensplat_command("os", tmp_path, 60, tmp_path / "o.ply")
    assert cmd[cmd.index("--warmup-length") + 1] == "70" and "--densify-from" not in cmd
    # the run passes the option the binary has
    seen = tmp_path / "seen.txt"
    run = _stand_in(tmp_path / "os12run", f"open({str(seen)!r}, 'w').write(' '.join(args))", _NEW_CLI)
    res = opensplat.run_opensplat(run, tmp_path, iters=5)
    assert "--densify-until 15" in seen.read_text() and res.timing == "whole run incl. startup"
    with pytest.raises(InputError, match="is it OpenSplat"):
        opensplat.opensplat_info(_stand_in(tmp_path / "other", "", cli="print('usage: other')"))


def test_runner_times_step_lines_with_a_stand_in_binary(tmp_path):
    """A stand-in executable checks the command line and the project, then prints OpenSplat-style
    progress; the runner must time from the step lines and record the command."""
    _, _, _, _, root = _project(tmp_path)
    fake = tmp_path / "opensplat"
    fake.write_text(f"""#!{sys.executable}
import json, sys, time, pathlib
args = sys.argv[1:]
{_OLD_CLI}
proj = pathlib.Path(args[0])
assert "--cpu" in args and args[args.index("-n") + 1] == "30" and args[args.index("-d") + 1] == "1"
assert args[args.index("--num-downscales") + 1] == "0" and int(args[args.index("--warmup-length") + 1]) > 30
meta = json.loads((proj / "transforms.json").read_text())
assert all((proj / f["file_path"]).is_file() for f in meta["frames"])
print("Reading", len(meta["frames"]), "cameras", flush=True)
for k in range(1, 31):
    t = time.process_time()
    while time.process_time() - t < 0.004:  # an iteration's CPU work
        pass
    if k % 10 == 0:
        print(f"Step {{k}}: 0.25 ({{100 * k // 30}}%)", flush=True)
""")
    fake.chmod(fake.stat().st_mode | stat.S_IXUSR)
    res = opensplat.run_opensplat(fake, root, iters=30)
    assert res.timing == "step lines 10..30" and res.s_per_iter > 0 and res.iters == 30
    assert res.command[0] == str(fake) and "--cpu" in res.command
    # CPU time of the child: per iteration from its /proc stat at the step lines, and the whole run
    assert res.cpu_timing == "step lines 10..30" and res.cpu_s_per_iter is not None
    assert 0.002 <= res.cpu_s_per_iter <= 0.05 and res.cpu_s_total >= 30 * 0.004 * 0.9
    row = train_step.opensplat_row(res, s_it=res.s_per_iter / 4.0, cpu_s_it=res.cpu_s_per_iter / 2.0)
    assert row["speedup_vs_opensplat"] == 4.0 and row["opensplat_timing"] == "step lines 10..30"
    assert row["cpu_speedup_vs_opensplat"] == 2.0 and row["opensplat_cpu_timing"] == "step lines 10..30"


def _stand_in_result(s_it, cpu_it):
    return opensplat.OpenSplatResult(s_per_iter=s_it, timing="step lines 1..60", iters=60, wall_s=60 * s_it,
                                     command=["opensplat", "proj"], cpu_s_per_iter=cpu_it,
                                     cpu_timing="step lines 1..60", cpu_s_total=60 * cpu_it)


def test_alternate_takes_turns_and_reads_the_load_around_every_run():
    log = []
    loads = iter(f"{x:.2f} 1.00 1.00 1/90 123" for x in range(100))

    def loadavg():
        log.append("load")
        return next(loads)

    def ours():
        log.append("ours")
        return {"s_per_iter": 0.1 * (1 + log.count("ours")), "cpu_s_per_iter": 0.15, "fragments": 1000.0}

    def theirs():
        log.append("theirs")
        return _stand_in_result(0.6 * log.count("theirs"), 0.8)

    runs = train_step.alternate(ours, theirs, 3, loadavg=loadavg)
    assert [x for x in log if x != "load"] == ["ours", "theirs"] * 3
    assert log[:6] == ["load", "ours", "load", "load", "theirs", "load"]
    row = train_step.summarize_row(runs, backend="cpu", n=30, width=10, height=10)
    # medians over the runs: ours 0.2/0.3/0.4 -> 0.3, theirs 0.6/1.2/1.8 -> 1.2
    assert row["s_per_iter"] == 0.3 and row["opensplat_s_per_iter"] == 1.2 and row["speedup_vs_opensplat"] == 4.0
    assert row["cpu_speedup_vs_opensplat"] == round(0.8 / 0.15, 2) and row["repeats"] == 3
    assert row["ns_per_fragment"] == round(0.3e9 / 1000, 2) and row["fragments_per_pixel"] == 10.0
    assert row["load_avg_range"] == [0.0, 11.0] and len(row["runs"]) == 3
    assert row["runs"][1]["opensplat"]["s_per_iter"] == 1.2 and row["runs"][0]["load_before"].startswith("0.00")
    assert "not run" not in train_step.format_table([row]).splitlines()[1]
    json.dumps(row)  # JSON-ready


def test_alternate_without_opensplat_repeats_ours_only():
    runs = train_step.alternate(lambda: {"s_per_iter": 0.2, "cpu_s_per_iter": 0.3, "fragments": 5.0}, None, 2,
                                loadavg=lambda: "1.00 1.00 1.00 1/9 9")
    row = train_step.summarize_row(runs, backend="cpu", n=3, width=1, height=1)
    assert len(runs) == 2 and all("opensplat" not in r for r in runs) and "opensplat_s_per_iter" not in row
    assert "not run" in train_step.format_table([row]).splitlines()[1]


def test_process_cpu_seconds_of_self_and_of_nobody():
    import os

    t = opensplat.process_cpu_s(os.getpid())
    assert t is None or t > 0
    assert opensplat.process_cpu_s(2 ** 31 - 1) is None


def test_failing_binary_reports_its_output(tmp_path):
    fake = _stand_in(tmp_path / "broken", "print('cannot read project'); raise SystemExit(3)")
    with pytest.raises(InputError, match="status 3.*\\n.*cannot read project"):
        opensplat.run_opensplat(fake, tmp_path, iters=5)


def test_seconds_per_iter_without_step_lines_counts_the_whole_run():
    assert opensplat.seconds_per_iter([], wall_s=12.0, iters=60) == (0.2, "whole run incl. startup")
    assert opensplat.seconds_per_iter([(1.0, 10), (1.0, 10), (3.0, 20)], 9.0, 20) == (0.2, "step lines 10..20")


def test_not_run_table_cites_the_last_side_by_side_and_divides_by_none():
    rows = [{"n_gaussians": 30_000, "width": 640, "height": 360, "s_per_iter": 0.5, "cpu_s_per_iter": 0.9,
             "fragments_per_pixel": 230.0, "ns_per_fragment": 9.6, "load_avg": 1.0}]
    table = train_step.format_table(rows)
    first_row = table.splitlines()[1]
    assert "not run" in first_row and not any(c.endswith("x") for c in first_row.split()[-5:])  # no speed-up
    assert "cited, not measured here" in table and "2026-11-24" in table and "OpenSplat 1.2.0" in table
    # 30k at 640x360: OpenSplat then / fixer4d then, wall and CPU
    assert "1.185 / 0.186 wall, 2.268 / 0.345 CPU" in table
    assert not hasattr(train_step, "OPENSPLAT_S")  # the old hard-coded divisors are gone
    cited = train_step.cited_json()
    assert cited["opensplat_s_per_iter"]["100000 640x360"] == 1.513
    assert cited["fixer4d_cpu_s_per_iter_then"]["100000 640x360"] == 0.485
    json.dumps(cited)


def test_missing_binary_fails_before_timing(tmp_path):
    with pytest.raises(InputError, match="not an executable"):
        train_step.main(["--data", str(tmp_path), "--opensplat", str(tmp_path / "nope"), "--out",
                         str(tmp_path / "o.json")])
