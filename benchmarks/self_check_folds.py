"""The stage-2 self-check alone under other settings, on a finished run's scene and config: what a
check with more held-back cameras, another scale or a scaled Gaussian budget decides and costs.

    python benchmarks/self_check_folds.py RUN [--set self_check.KEY=VALUE ...] [--out FILE.json]

The config is RUN's own (config.json) with the ``--set`` overrides applied as `fixer4d run --set`
would; the check runs exactly as the pipeline runs it (``pipeline.self_check_run.run_self_check``,
the run's restorer from RUN/restorer, a learned one trained again inside each fold) in a
temporary folder. RUN itself is only read. The output holds the decision, each candidate's figure,
the paired gains ± standard error, the check's seconds (wall and CPU, this process) and, for
comparison, the seconds RUN's own check and stages took (measured under that run's load).
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import fixer4d  # noqa: F401  (sets the numerics and the OpenMP wait policy before torch is imported)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path, help="a finished fixer4d run folder")
    parser.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE",
                        help="config override, e.g. self_check.cameras=2 (repeatable)")
    parser.add_argument("--out", type=Path, default=None, help="also write the result as JSON")
    args = parser.parse_args(argv)

    from fixer4d.pipeline import config_tree
    from fixer4d.pipeline.config import resolve
    from fixer4d.pipeline.restoration import run_restorer
    from fixer4d.pipeline.run_folder import load_scene_for, read_run_config
    from fixer4d.pipeline.self_check_run import run_self_check
    from fixer4d.scene.train_view import TrainOnlyView

    if not (args.run / "config.json").is_file():
        print(f"{args.run}: no config.json; give a finished `fixer4d run` folder", file=sys.stderr)
        return 2
    config = resolve(config_file=read_run_config(args.run).to_dict(),
                     overrides=config_tree.parse_set_overrides(args.sets), defaults={})
    scene = TrainOnlyView(load_scene_for(config))
    restorer = None if config.restorer.kind == "learned" else run_restorer(config, args.run)
    with tempfile.TemporaryDirectory(prefix="self_check_") as tmp:
        cpu0, wall0 = time.process_time(), time.perf_counter()
        record = run_self_check(scene, config, Path(tmp) / "self_check", restorer, progress=False)
        cpu, wall = time.process_time() - cpu0, time.perf_counter() - wall0
    report = json.loads((args.run / "report.json").read_text()) if (args.run / "report.json").is_file() else {}
    run_seconds = report.get("stage_seconds", {})
    result = {"run": str(args.run), "sets": args.sets, "decision": record["decision"], "psnr": record["psnr"],
              "gains": record.get("gains"), "gain_unit": record.get("gain_unit"),
              "held_back": record.get("held_back_names"), "check_wall_s": wall, "check_cpu_s": cpu,
              "check_parts_s": record.get("seconds"),
              "run_check_s": run_seconds.get("self_check"), "run_stages_s": sum(run_seconds.values()) or None,
              "run_decision": (report.get("self_check") or {}).get("decision"),
              "folds": [{"held_back": f["held_back_name"], "psnr": f["psnr"]} for f in record.get("folds", [])]}
    gains = ", ".join(f"{c} {g['gain_db']:+.2f} ± {g['se_db'] or 0:.2f}" for c, g in (record.get("gains") or {}).items())
    print(f"{' '.join(args.sets) or '(run config)'}: {record['decision']} ({gains} dB per {record.get('gain_unit')}); "
          f"{wall:.0f} s wall, {cpu:.0f} CPU s; the run's own check: {result['run_decision']}, "
          f"{result['run_check_s'] or 0:.0f} s of {result['run_stages_s'] or 0:.0f} s")
    if args.out is not None:
        args.out.write_text(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
