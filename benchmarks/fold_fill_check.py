"""Can the train cameras alone tell whether the restorer or the unobserved fill should repair the
pixels no train camera sees? Per pixel class, on the learned restorer's held-back fold.

    python benchmarks/fold_fill_check.py RUN [--out FILE.json]

RUN is a finished `fixer4d run` folder with the learned restorer. Its validation fold (the train
camera whose pairs the restorer never learned from, ``validation.json``) is trained again on the
other three train cameras, exactly as the restorer's pairs were made; at the pair timestamps the
held-back camera is rendered, its unobserved weight computed from the three cameras' renders
(``restore.visibility``), and the render, the restorer's output, the fill
(``restore.unobserved_fill``) and the Restoration rows' gate (``gate_restoration`` with the fill)
are scored against its real frame over the classes all, unobserved (weight > 0.5) and observed.

Only train cameras are read, so any verdict here could choose a setting per run. Compare with
``benchmarks/restoration_gate.py`` on the validation cameras (docs/decisions/unobserved-fill.md, "Also tried"): a fold
that agrees with them where they agree, and tells the test camera apart where it differs, would
be a signal for the gate.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import fixer4d  # noqa: E402,F401  (sets the OpenMP wait policy before torch is imported)

IMAGES = ("render", "restored", "fill", "gate")
CLASSES = ("all", "unobserved", "observed")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path)
    parser.add_argument("--out", type=Path, default=None, help="write the table as JSON")
    args = parser.parse_args(argv)

    from fixer4d.errors import InputError
    from fixer4d.eval.class_psnr import ClassPSNR
    from fixer4d.init import load_frame_clouds
    from fixer4d.init.decompose import DecomposedInit, has_decomposed
    from fixer4d.pipeline.restoration import RESTORER_DIR, gate_restoration, run_restorer
    from fixer4d.pipeline.run_folder import load_scene_for, read_run_config, source_commit
    from fixer4d.render.views import render_views
    from fixer4d.restore.config import VALIDATION_FILE
    from fixer4d.restore.unobserved_fill import fill_unobserved
    from fixer4d.restore.visibility import TrainView, unobserved_weight
    from fixer4d.scene.train_view import TrainOnlyView
    from fixer4d.train.restorer_pairs import fold_trainer, pair_frames, pair_request

    config = read_run_config(args.run)
    if config.restorer.kind != "learned":
        raise InputError(f"{args.run}: the check needs a run with the learned restorer (has {config.restorer.kind})")
    held = json.loads((args.run / RESTORER_DIR / VALIDATION_FILE).read_text())["held_out_fold_camera"]
    init_dir = args.run / f"init_{config.init_method}"  # the run's init as stored (the folder is only read)
    clouds = DecomposedInit.load(init_dir) if has_decomposed(init_dir) else load_frame_clouds(init_dir)
    restorer = run_restorer(config, args.run)
    visibility = config.stage2.visibility
    scene = TrainOnlyView(load_scene_for(config))
    stage1 = dataclasses.replace(config.training, progress=False)
    trainer, full = fold_trainer(scene, clouds, stage1, held, config.restorer)
    trainer.train(progress=False)
    model, backend, background = trainer.model, trainer.config.backend, trainer.background
    others = [i for i in scene.train_ids if i != held]
    psnr = ClassPSNR(IMAGES, CLASSES)
    frames = pair_frames(scene.num_frames, config.restorer.learned.pair_frames)
    for f in frames:
        request = pair_request(model, full, held, f, backend, background)
        _, depth, alpha = render_views(model, [full.cameras[i] for i in others], request.time, backend, background)
        views = [TrainView(full.cameras[i], d, a) for i, d, a in zip(others, depth, alpha)]
        request.unobserved = unobserved_weight(request.cameras[0], request.depth[0], request.alpha[0], views,
                                               visibility)[None]
        result = restorer.restore(request)
        imgs = {"render": request.rgb[0], "restored": result.rgb[0],
                "fill": fill_unobserved(request.rgb, request.unobserved, request.depth, request.alpha)[0],
                "gate": gate_restoration(request, result, visibility, fill=True).rgb[0]}
        hidden = request.unobserved[0] > 0.5
        psnr.add(full.frame(f, held), imgs, {"all": np.ones_like(hidden), "unobserved": hidden, "observed": ~hidden})
    psnr.report(args.out, run=str(args.run), held_back_train_camera=int(held), frames=frames,
                restorer=config.restorer.kind, commit=source_commit())
    return 0


if __name__ == "__main__":
    sys.exit(main())
