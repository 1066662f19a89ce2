"""`fixer4d bench quality`: the held-out rows over several seeds, with their 95 % intervals and the
paired differences that decide between options.

A single run reads to about ±0.3–1 dB (stage 1 is chaotic in its seed), more than most of the
differences a decision is about; a difference between two rows of the *same* run (Full − STGS w/
MVS, both from one stage-1 model) moves much less from seed to seed. So for each camera set and
each seed this runs the README's command for that set (``fixer4d run SCENE --seed S ...``, then
``fixer4d eval RUN --cameras-from VAL`` for its validation cameras), records each report as a
result file (``<out>/<set>[_val]_seed<S>.json``: rows, config, commit, CPU, numerics mode), and
summarizes them in ``<out>/summary.json``:

* each row's mean, standard deviation and 95 % confidence half-width (Student t, n − 1 degrees
  of freedom) over the seeds, per metric (PSNR over all, dynamic and unobserved pixels,
  exposure-aligned PSNR, LPIPS);
* the **paired** differences per seed, with their own intervals: Full − STGS w/ MVS,
  Full − matched (the same iterations without pseudo-views), Restoration (init) − STGS w/ MVS
  (the render itself is the identity baseline).

``--against OUT`` pairs these result files with another option's, seed by seed (``compare``):
per split and row, the difference this − that per seed with its interval, written to
``<out>/against_<name of OUT>.json``.

Resumable: a finished (set, seed) is read back from its result file; a killed run resumes inside
``fixer4d run``'s own run folder. Progress is printed before each run. Runs happen in child
processes, so each starts with the numerics mode of this process's environment (portable by
default: the same digits on any x86-64 host, ``fixer4d.numerics``).
"""
from __future__ import annotations

import argparse
import dataclasses
import datetime
import json
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Callable, Sequence

from fixer4d.stats import interval

REPO_ROOT = Path(__file__).resolve().parents[2]
DATA_ROOT = REPO_ROOT.parent / "shared" / "data"
DEFAULT_OUT = REPO_ROOT / "benchmarks" / "results" / "quality"
DEFAULT_RUNS = Path("runs") / "quality"
# The README's Panoptic settings (half resolution, 30 frames; the learned restorer).
PANOPTIC_ARGS = ("--restorer", "learned", "--scale", "0.5", "--frames", "0:30", "--iterations", "1500",
                 "--refresh-every", "200", "--set", "training.init_max_points=30000", "--set", "training.max_gaussians=40000",
                 "--set", "trajectories.frames=8", "--set", "trajectories.time_stride=6", "--set", "init_frame_stride=6",
                 "--set", "eval.stride=3")
METRICS = ("psnr", "psnr_dynamic", "psnr_unobserved", "psnr_aligned", "lpips")
ROW_MVS = "STGS w/ MVS"
ROW_MATCHED = "STGS w/ MVS (matched iterations)"
ROW_RESTORED = "Restoration (init)"
ROW_FULL = "Full"
#: (label, minuend row, subtrahend row): the paired differences reported per seed.
PAIRS = (("Full - STGS w/ MVS", ROW_FULL, ROW_MVS), ("Full - matched", ROW_FULL, ROW_MATCHED),
         ("Restoration (init) - identity", ROW_RESTORED, ROW_MVS))


@dataclasses.dataclass(frozen=True)
class CameraSet:
    """One scene with its test cameras (the run's held-out ones) and, if any, a folder of
    validation cameras (same train cameras, other held-out ones). ``validation_only``: a synthetic
    scene other than the demo, whose held-out cameras are all validation cameras."""

    name: str
    scene: str
    args: tuple[str, ...] = ()
    validation: str | None = None
    validation_only: bool = False

    def available(self) -> str | None:
        """None when the set can run here, else why not (a data folder that is absent)."""
        for path in (self.scene, self.validation):
            if path is not None and ("/" in path) and not Path(path).exists():
                return f"{path} is absent"
        return None


def camera_sets(data_root: Path = DATA_ROOT) -> dict[str, CameraSet]:
    """Every camera set the bench knows, by name."""
    sets = [CameraSet("demo", "demo", validation="demo_val"),
            CameraSet("panoptic", str(data_root / "panoptic_basketball"), PANOPTIC_ARGS,
                      str(data_root / "panoptic_basketball_val")),
            CameraSet("panoptic_c", str(data_root / "panoptic_basketball_c"), PANOPTIC_ARGS,
                      str(data_root / "panoptic_basketball_c_val"))]
    sets += [CameraSet(name, name, validation_only=True) for name in ("fast_thin", "slow_rigid", "static_matte")]
    return {s.name: s for s in sets}


def _rows(record: dict[str, Any]) -> dict[str, dict[str, Any]]:
    return {r["method"]: r for r in record.get("rows", []) if r.get("status", "ok") == "ok"}


def summarize_split(records: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """The summary of one camera split over its seeds' result files: per row and metric the
    ``interval``, and per pair of ``PAIRS`` and metric the interval of the per-seed differences
    (seeds missing either row dropped); ``failed``: the rows that failed in every seed."""
    per_seed = [_rows(r) for r in records]
    methods = [m for m in dict.fromkeys(k for rows in per_seed for k in rows)]
    rows = {m: {k: interval([rows[m].get(k) for rows in per_seed if m in rows]) for k in METRICS} for m in methods}
    paired = {}
    for label, a, b in PAIRS:
        both = [rows for rows in per_seed if a in rows and b in rows]
        if not both:
            continue
        paired[label] = {k: interval([(r[a].get(k) - r[b].get(k)) if r[a].get(k) is not None and r[b].get(k) is not None
                                      else None for r in both]) for k in METRICS}
    decisions = [((r.get("self_check") or {}).get("decision") or "off") for r in records]
    failed = sorted({r["method"] for rec in records for r in rec.get("rows", []) if r.get("status") == "failed"}
                    - set(rows))
    return {"seeds": [r.get("seed") for r in records], "rows": rows, "failed": failed, "paired": paired,
            "self_check": decisions}


# ---------------------------------------------------------------- records

def record_run(report_dir: Path, name: str, command: str, seed: int | None = None,
               note: str | None = None) -> dict[str, Any]:
    """A result record of the report in ``report_dir`` (a run folder, or a RUN/heldout/<folder>
    scored by ``fixer4d eval --cameras-from``): its rows and self-check, the run's config and
    stage seconds (those of the run that trained the scored models), the command, seed, note,
    commit (the run folder's own stamp wins over the checkout at record time), date, CPU, load and
    numerics mode."""
    from fixer4d.bench.machine import cpu_topology
    from fixer4d.pipeline.run_folder import source_commit

    report = json.loads((report_dir / "report.json").read_text())
    run_dir = report_dir if (report_dir / "config.json").is_file() else Path(report["run"])
    config = json.loads((run_dir / "config.json").read_text())
    stage_seconds = report.get("stage_seconds")
    if not stage_seconds and (run_dir / "report.json").is_file():
        stage_seconds = json.loads((run_dir / "report.json").read_text()).get("stage_seconds")
    run_report = json.loads((run_dir / "report.json").read_text()) if (run_dir / "report.json").is_file() else report
    cpu = cpu_topology()
    return {"name": name, "command": command, "seed": seed, "note": note,
            "commit": config.get("source_commit") or source_commit(), "date": datetime.date.today().isoformat(),
            "machine": {"cores": os.cpu_count(), "cpu": cpu["cpu"],
                        "cpu_family_model": [cpu.get("cpu_family"), cpu.get("model")],
                        "load_average_at_record": list(os.getloadavg())},
            "numerics": run_report.get("numerics") or report.get("numerics"),
            "rows": report["rows"], "self_check": report.get("self_check") or run_report.get("self_check"),
            "stage_seconds": stage_seconds, "scene": report.get("scene"), "heldout_from": report.get("heldout_from"),
            "config": config}


# ---------------------------------------------------------------- the bench

def _cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "fixer4d.cli", *args]


def _run_child(argv: list[str], log: Callable[[str], None]) -> None:
    log("$ " + " ".join(argv[2:]).replace("fixer4d.cli", "fixer4d", 1))
    done = subprocess.run(argv, cwd=os.getcwd())
    if done.returncode:
        raise RuntimeError(f"`{' '.join(argv[3:])}` exited {done.returncode}; fix it and run the bench again "
                           "(finished runs are kept)")


def run_set(cs: CameraSet, seed: int, runs: Path, out: Path, log: Callable[[str], None] = print,
            runner: Callable[[list[str], Callable[[str], None]], None] = _run_child,
            overrides: Sequence[str] = ()) -> list[Path]:
    """Run (or resume) ``cs`` at ``seed`` and write its result file(s); returns their paths.
    overrides: ``KEY=VALUE`` settings added to the set's command (``--set``), an option under test."""
    run_dir = runs / cs.name / f"seed{seed}"
    args = (*cs.args, *(a for kv in overrides for a in ("--set", kv)))
    command = f"fixer4d run {cs.scene} --out {run_dir} --seed {seed} " + " ".join(args)
    test_file = out / f"{cs.name}{'_val' if cs.validation_only else ''}_seed{seed}.json"
    written = []
    if not test_file.is_file():
        runner(_cli("run", cs.scene, "--out", str(run_dir), "--seed", str(seed), *args), log)
        _write(test_file, record_run(run_dir, test_file.stem, command.strip(), seed))
    written.append(test_file)
    if cs.validation is not None:
        val_file = out / f"{cs.name}_val_seed{seed}.json"
        if not val_file.is_file():
            runner(_cli("eval", str(run_dir), "--cameras-from", cs.validation, "--quiet"), log)
            val_dir = run_dir / "heldout" / Path(cs.validation).name
            _write(val_file, record_run(val_dir, val_file.stem,
                                        f"{command.strip()}; fixer4d eval {run_dir} --cameras-from {cs.validation}",
                                        seed))
        written.append(val_file)
    return written


def _write(path: Path, data: dict[str, Any]) -> None:
    from fixer4d.atomic import write_json

    path.parent.mkdir(parents=True, exist_ok=True)
    write_json(path, data)


def _result_files(out: Path) -> dict[str, list[tuple[int, Path]]]:
    """The result files in ``out`` by split (``<set>`` or ``<set>_val``): [(seed, path)], by seed."""
    groups: dict[str, list[tuple[int, Path]]] = {}
    for path in sorted(out.glob("*_seed*.json")):
        split, _, seed = path.stem.rpartition("_seed")
        if seed.isdigit():
            groups.setdefault(split, []).append((int(seed), path))
    return {split: sorted(files) for split, files in groups.items()}


def summarize(out: Path) -> dict[str, Any]:
    """``summary.json`` of every result file in ``out``: per split (``<set>`` or ``<set>_val``)
    the ``summarize_split`` of its seeds, with the files it read."""
    groups = _result_files(out)
    summary = {}
    for split, files in sorted(groups.items()):
        records = [json.loads(p.read_text()) for _, p in sorted(files)]
        for (seed, _), r in zip(sorted(files), records):
            r.setdefault("seed", seed)
        summary[split] = {**summarize_split(records), "files": [p.name for _, p in sorted(files)],
                          "commits": sorted({str(r.get("commit")) for r in records}),
                          "numerics": sorted({str((r.get("numerics") or {}).get("mode", "unrecorded")) for r in records})}
    return summary


#: The rows two options are compared on (``compare``).
COMPARED_ROWS = (ROW_MVS, ROW_RESTORED, ROW_FULL)


def compare(out: Path, against: Path) -> dict[str, Any]:
    """One option against another, paired per seed: for each split both result folders have,
    over the seeds both have, each row of ``COMPARED_ROWS`` as (``out``'s − ``against``'s) per
    seed, with its ``interval`` per metric, and both options' self-check decisions."""
    mine, theirs = _result_files(out), _result_files(against)
    result: dict[str, Any] = {}
    for split in sorted(set(mine) & set(theirs)):
        a_files, b_files = dict(mine[split]), dict(theirs[split])
        seeds = sorted(set(a_files) & set(b_files))
        if not seeds:
            continue
        a = [json.loads(a_files[s].read_text()) for s in seeds]
        b = [json.loads(b_files[s].read_text()) for s in seeds]
        rows = {}
        for row in COMPARED_ROWS:
            diffs = {k: [(ra[row][k] - rb[row][k]) if row in ra and row in rb and ra[row].get(k) is not None
                         and rb[row].get(k) is not None else None for ra, rb in zip(map(_rows, a), map(_rows, b))]
                     for k in METRICS}
            if any(v is not None for v in diffs["psnr"]):
                rows[row] = {k: {**interval(v), "values": v} for k, v in diffs.items()}
        result[split] = {"seeds": seeds, "rows": rows,
                         "self_check": [[((r.get("self_check") or {}).get("decision") or "off") for r in recs]
                                        for recs in (a, b)]}
    return result


def compare_markdown(comparison: dict[str, Any]) -> str:
    """The table of ``compare``: per split, each row's paired PSNR difference ± 95 % half-width and
    its per-seed values (test splits first, then validation)."""
    head = ["split (seeds)", *(f"{r} (paired)" for r in COMPARED_ROWS), "self-check (this / that)"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for split in sorted(comparison, key=lambda s: (s.endswith("_val"), s)):
        c = comparison[split]
        cells = []
        for row in COMPARED_ROWS:
            iv = c["rows"].get(row, {}).get("psnr")
            per_seed = ", ".join("n/a" if v is None else f"{v:+.2f}" for v in (iv or {}).get("values", []))
            cells.append(f"{_fmt(iv, signed=True)} ({per_seed})" if iv else "")
        checks = " / ".join("".join(d[0] for d in side) for side in c["self_check"])
        lines.append(f"| {split} ({', '.join(str(s) for s in c['seeds'])}) | " + " | ".join(cells + [checks]) + " |")
    return "\n".join(lines)


def _fmt(iv: dict[str, Any] | None, signed: bool = False) -> str:
    if not iv or iv.get("mean") is None:
        return ""
    mean = f"{iv['mean']:+.2f}" if signed else f"{iv['mean']:.2f}"
    return mean if iv.get("ci95") is None else f"{mean} ± {iv['ci95']:.2f}"


TABLE_ROWS = ("STGS w/ COLMAP", ROW_MVS, ROW_MATCHED, ROW_RESTORED, ROW_FULL)


def markdown(summary: dict[str, Any], link_prefix: str = "benchmarks/results/quality/") -> str:
    """The results table: per split, each row's PSNR mean ± 95 % half-width over the seeds and the
    paired Full − STGS w/ MVS and Full − matched differences (test splits first, then validation)."""
    head = ["split (seeds)", *TABLE_ROWS, "Full − MVS (paired)", "Full − matched (paired)", "self-check"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    order = sorted(summary, key=lambda s: (s.endswith("_val"), s))
    for split in order:
        s = summary[split]
        label = f"*{split}*" if split.endswith("_val") else split
        seeds = ", ".join(str(x) for x in s["seeds"])
        cells = ["failed" if r in s.get("failed", ()) else _fmt(s["rows"].get(r, {}).get("psnr")) for r in TABLE_ROWS]
        paired = [_fmt(s["paired"].get(k, {}).get("psnr"), signed=True) for k in ("Full - STGS w/ MVS", "Full - matched")]
        checks = "/".join(sorted(set(s["self_check"])))
        lines.append(f"| [{label}]({link_prefix}{s['files'][0]}) ({seeds}) | " + " | ".join(cells + paired + [checks])
                     + " |")
    return "\n".join(lines)


BEGIN = "<!-- QUALITY:BEGIN (generated by fixer4d bench quality --summary-only --readme README.md; do not edit) -->"
END = "<!-- QUALITY:END -->"


def block(summary: dict[str, Any]) -> str:
    """The README's generated results block: ``markdown(summary)`` between the QUALITY markers."""
    return f"{BEGIN}\n{markdown(summary)}\n{END}"


def write_block(path: Path, summary: dict[str, Any]) -> None:
    """Replace the block between the QUALITY markers of ``path`` with ``block(summary)``."""
    text = path.read_text()
    if BEGIN not in text or END not in text:
        raise SystemExit(f"{path}: no {BEGIN!r} ... {END!r} block to fill")
    head, rest = text.split(BEGIN, 1)
    path.write_text(head + block(summary) + rest.split(END, 1)[1])


def main(argv: list[str] | None = None) -> int:
    sets = camera_sets()
    parser = argparse.ArgumentParser(prog="fixer4d bench quality", description=__doc__.split("\n\n")[0])
    parser.add_argument("--sets", default="demo,panoptic,panoptic_c",
                        help=f"comma-separated camera sets ({', '.join(sets)}; default demo,panoptic,panoptic_c)")
    parser.add_argument("--seeds", default="0,1,2", help="comma-separated seeds (default 0,1,2)")
    parser.add_argument("--runs", type=Path, default=DEFAULT_RUNS, help="where the run folders go (kept, resumable)")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, help="result files and summary.json")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                        help="a setting added to every run's command (repeatable): an option under test; give "
                             "it its own --runs and --out")
    parser.add_argument("--summary-only", action="store_true", help="only summarize the result files in --out")
    parser.add_argument("--against", type=Path, default=None, metavar="OUT",
                        help="also pair these result files with another option's (its --out), seed by seed: "
                             "writes <out>/against_<name>.json and prints the paired table")
    parser.add_argument("--readme", type=Path, default=None,
                        help="also rewrite the results block of this Markdown file (README.md) from the summary")
    args = parser.parse_args(argv)
    names = [s for s in args.sets.split(",") if s]
    unknown = [s for s in names if s not in sets]
    if unknown:
        parser.error(f"unknown camera set(s) {unknown}; choose from {', '.join(sets)}")
    seeds = [int(s) for s in args.seeds.split(",") if s]
    if not args.summary_only:
        todo = [(sets[n], s) for n in names for s in seeds]
        t0 = time.perf_counter()
        for i, (cs, seed) in enumerate(todo, 1):
            why = cs.available()
            if why is not None:
                print(f"[quality] {cs.name}: skipped ({why})", flush=True)
                continue
            print(f"[quality] {i}/{len(todo)}: {cs.name}, seed {seed} ({time.perf_counter() - t0:.0f} s so far)",
                  flush=True)
            run_set(cs, seed, args.runs, args.out, log=lambda m: print(f"[quality] {m}", flush=True),
                    overrides=args.overrides)
    summary = summarize(args.out)
    _write(args.out / "summary.json", summary)
    if args.readme is not None:
        write_block(args.readme, summary)
    out = args.out.resolve()
    print(markdown(summary, link_prefix=f"{out.relative_to(REPO_ROOT) if out.is_relative_to(REPO_ROOT) else out}/"))
    if args.against is not None:
        comparison = compare(args.out, args.against)
        _write(args.out / f"against_{args.against.name}.json", {"this": str(args.out), "that": str(args.against),
                                                                "splits": comparison})
        print(f"\n{args.out} − {args.against}, paired per seed (dB):\n" + compare_markdown(comparison))
    return 0


__all__ = ["CameraSet", "camera_sets", "summarize_split", "record_run", "run_set", "summarize", "markdown", "block",
           "write_block", "compare", "compare_markdown", "main"]
