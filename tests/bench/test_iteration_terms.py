"""`fixer4d bench iteration --model-terms`: the three models it compares, and the clip it opens."""
from __future__ import annotations

import json

from fixer4d.bench.iteration import main
from fixer4d.init.decompose import DecomposedInit


def test_terms_rows_compare_the_init_at_its_own_size(tmp_path):
    out = tmp_path / "terms.json"
    init_dir = tmp_path / "init"
    from fixer4d.init import run_init
    from fixer4d.scene import load_scene

    scene = load_scene("tiny", frame_range=(1, 4))
    run_init(scene, "mvs", init_dir, frames=[0, 1, 2], progress=False)
    init = DecomposedInit.load(init_dir)
    assert main(["--model-terms", "--scene", "tiny", "--frames", "1:4", "--init-stride", "1", "--init", str(init_dir),
                 "--max-points", "1000000", "--iterations", "1", "--warmup", "0", "--out", str(out)]) == 0
    result = json.loads(out.read_text())
    assert result["frame_range"] == [1, 4] and result["init_frames"] == [0, 1, 2]
    rows = result["rows"]
    # without a binding cap the per-frame model repeats the static cloud once per init frame
    per_frame = rows["per_frame_all"]
    assert per_frame["num_gaussians"] == 3 * init.num_static + init.num_dynamic
    assert per_frame["num_dynamic"] == per_frame["num_gaussians"]
    assert rows["decomposed_all"]["num_gaussians"] <= init.num_static + init.num_dynamic
    assert rows["decomposed_all"]["num_dynamic"] == rows["decomposed_all"]["num_gaussians"]
    auto = rows["decomposed_auto"]
    assert 0 < auto["num_dynamic"] < auto["num_gaussians"] < per_frame["num_gaussians"]
    assert set(result["speedup_auto_vs"]) == set(rows) and result["speedup_auto_vs"]["decomposed_auto"] == 1.0


def test_terms_rows_at_a_binding_cap_hold_the_cap(tmp_path):
    out = tmp_path / "terms.json"
    assert main(["--model-terms", "--scene", "tiny", "--frames", "1:4", "--init-stride", "1", "--max-points", "500",
                 "--iterations", "1", "--warmup", "0", "--out", str(out)]) == 0
    rows = json.loads(out.read_text())["rows"]
    assert {r["num_gaussians"] for r in rows.values()} == {500}
