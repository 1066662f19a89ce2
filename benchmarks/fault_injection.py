"""Fault injection: SIGKILL `fixer4d run tiny` at random points of every stage, resume, compare.

    python benchmarks/fault_injection.py --out /tmp/fi --kills 10 [--seed 0] [--json result.json]

1. Uninterrupted reference runs of the tiny scene (``TINY_SETTINGS``) into
   OUT/reference_<i> (``--references``, default 2: the first also compiles and warms caches).
   They must agree exactly (else the pipeline is nondeterministic without any kill). The last
   one's stage timeline (when each stage name appears in RUN/stages.json, measured from the
   moment the process rewrote RUN/config.json) gives every stage's duration.
2. A second run folder OUT/killed: ``--kills`` times, start (or resume) the same command,
   wait until the target stage is under way, sleep a random fraction of that stage's reference
   duration and SIGKILL the process group. Targets cycle through every stage so each gets at
   least one kill when there are at least as many kills as stages (the rest on random stages);
   where a kill lands is read back from stages.json. A kill that overshoots into a later stage
   (the stage ran faster than in the reference) is retried from a copy of the folder as the
   kill found it, at half the delay (``OVERSHOOT_RETRIES``); the coverage check reports stages
   no kill reached. Then one last resume runs to the end.
3. Checks (any failure makes the exit status 1):
   * report.json rows are equal to the reference's: method names, order and every metric
     (psnr, dssim1, dssim2, lpips) EXACTLY, tolerance 0. The pipeline is deterministic: every
     random draw comes from seeded generators whose states are checkpointed, so a resumed run
     replays the same arithmetic. Only ``seconds`` (wall time of the killed attempts differs)
     and ``stage_seconds`` are not compared.
   * the artifacts are byte-identical (models, init clouds, restored frames, eval metrics
     without seconds); a difference names the first file where the runs diverge.
   * no partial or temporary file anywhere in the run folder (hidden ``.name.*`` temporaries
     of atomic writes, ``*.tmp.*``/``*.old.*`` directories, cache/corrupt, cache/stale).
   * a config change is not served stale cache entries: the run is repeated into the killed
     folder with ``--change`` (default trajectories.seed=1, which moves the arc cameras of
     every restored clip). It must either be refused (one "error:" line, exit 2 -- the CLI
     returns 1 for every fixer4d error until the CLI restructure --, nothing in the folder
     touched) or produce cache entries equal to a fresh run of the changed config.

The pytest ``tests/test_fault_injection.py`` runs the same functions with ``FAST_SETTINGS``
and 3 kills. Results of a full run go to ``--json`` (and the README quotes them).
"""
from __future__ import annotations

import argparse
import hashlib
import json
import os
import random
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]

# The tiny scene with the settings of tests/pipeline (every stage, about a minute on 2 cores).
# Checkpoints every 10 steps (default: every few hundred) so that a kill mid-training resumes
# from a checkpoint rather than restarting the stage: the path under test.
TINY_SETTINGS = {
    "training.iterations": 40, "training.checkpoint_every": 10, "stage2.rounds": 1, "stage2.refresh_every": 20,
    "trajectories.frames": 3, "trajectories.time_stride": 4, "init_frame_stride": 2, "eval.stride": 2,
    "init.mvs.planes": 24,
}
# Smaller still for the pytest: no sparse baseline and no restoration rows (their stages are the
# same code paths as the main ones), half resolution, fewer steps.
FAST_SETTINGS = {
    "scene.scale": 0.5, "baseline_sparse": False, "eval.restoration_rows": False,
    "training.iterations": 16, "training.checkpoint_every": 4, "stage2.rounds": 1, "stage2.refresh_every": 8,
    "trajectories.frames": 3, "trajectories.time_stride": 4, "init_frame_stride": 4, "eval.stride": 4,
    "init.mvs.planes": 8,
}
# The config change of check 4: another trajectory seed draws other arc amplitudes, so every
# arc clip's cameras (and its restored frames) change.
DEFAULT_CHANGE = {"trajectories.seed": 1}
# How often the watcher reads stages.json / config.json (seconds): fine against stages of seconds.
POLL_S = 0.02
# A kill is placed at a uniform fraction of the target stage's reference duration in this
# range: away from the exact boundaries, which the neighbouring stages' kills already probe.
KILL_FRACTION = (0.05, 0.95)
# A kill that lands past its target stage (the stage ran faster than in the reference, e.g. the
# machine's load dropped) is retried this many times from a copy of the folder as it was, each
# time at half the delay.
OVERSHOOT_RETRIES = 3
# Reported metrics of a report row, compared exactly.
METRIC_KEYS = ("method", "psnr", "dssim1", "dssim2", "lpips")


def command(out: Path, settings: dict[str, Any], scene: str = "tiny") -> list[str]:
    """The ``fixer4d run`` command line for ``settings`` (each a ``--set KEY=JSON``)."""
    argv = [sys.executable, "-m", "fixer4d.cli", "run", scene, "--out", str(out), "--quiet"]
    for k, v in settings.items():
        argv += ["--set", f"{k}={json.dumps(v)}"]
    return argv


def _stages(run: Path) -> list[str]:
    """Finished stage names in the order stages.json lists them ([] while absent or mid-write)."""
    try:
        records = json.loads((run / "stages.json").read_text())
    except (OSError, ValueError):
        return []
    return [name for name, rec in records.items() if not isinstance(rec, dict) or rec.get("done")]


def _started(run: Path, launched_ns: int) -> bool:
    """Whether the process launched at ``launched_ns`` has written RUN/config.json (its config
    is validated and it is about to work on the stages)."""
    try:
        return (run / "config.json").stat().st_mtime_ns >= launched_ns
    except OSError:
        return False


@dataclass
class Attempt:
    """One launch: how it ended and what it finished."""

    returncode: int | None
    wall_s: float
    killed_after_s: float | None = None
    target: str | None = None
    landed: str | None = None  # first unfinished stage when the kill hit (None: finished everything)
    stderr_tail: str = ""
    timeline: dict[str, float] = field(default_factory=dict)  # stage -> seconds after start signal


def launch(out: Path, settings: dict[str, Any], *, kill_stage: str | None = None, order: list[str] | None = None,
           delay_s: float = 0.0, timeout_s: float = 1800.0) -> Attempt:
    """Run the pipeline into ``out``. With ``kill_stage``: once every stage before it in
    ``order`` is finished and the process has started, sleep ``delay_s`` and SIGKILL its
    process group. Returns the Attempt (timeline relative to the process's start signal)."""
    out.parent.mkdir(parents=True, exist_ok=True)
    launched_ns = time.time_ns()
    t_launch = time.perf_counter()
    proc = subprocess.Popen(command(out, settings), cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            start_new_session=True, text=True)
    before = set(_stages(out))
    t_start = None
    timeline: dict[str, float] = {}
    kill_at = None
    need = [] if kill_stage is None else order[: order.index(kill_stage)]
    try:
        while proc.poll() is None:
            now = time.perf_counter()
            if now - t_launch > timeout_s:
                raise TimeoutError(f"{out}: no end after {timeout_s} s")
            if t_start is None and _started(out, launched_ns):
                t_start = now
            done = _stages(out)
            if t_start is not None:
                for s in done:
                    if s not in before and s not in timeline:
                        timeline[s] = now - t_start
            if kill_stage is not None and kill_at is None and t_start is not None and set(need) <= set(done):
                kill_at = now + delay_s
            if kill_at is not None and now >= kill_at:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
                done = _stages(out)
                landed = next((s for s in order if s not in done), None)
                return Attempt(proc.returncode, time.perf_counter() - t_launch, now - t_launch, kill_stage, landed,
                               "", timeline)
            time.sleep(POLL_S)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    err = proc.stderr.read() if proc.stderr else ""
    return Attempt(proc.returncode, time.perf_counter() - t_launch, None, kill_stage, None, err[-2000:], timeline)


def stage_durations(timeline: dict[str, float]) -> dict[str, float]:
    """Seconds per stage from a timeline of stage end times (the first starts at 0)."""
    out, prev = {}, 0.0
    for name, end in sorted(timeline.items(), key=lambda kv: kv[1]):
        out[name] = max(end - prev, 0.0)
        prev = end
    return out


def plan_kills(durations: dict[str, float], kills: int, rng: random.Random) -> list[tuple[str, float]]:
    """(stage, delay seconds) per kill in stage order: every stage at least once when
    ``kills >= len(stages)``, the rest on random stages, each at a random fraction."""
    names = list(durations)
    targets = [names[i % len(names)] for i in range(min(kills, len(names)))]
    targets += [rng.choice(names) for _ in range(kills - len(targets))]
    if kills < len(names):  # fewer kills than stages: random distinct stages
        targets = rng.sample(names, kills)
    targets.sort(key=names.index)
    return [(s, rng.uniform(*KILL_FRACTION) * durations[s]) for s in targets]


# ---- checks ---------------------------------------------------------------------------------
def compare_reports(ref: dict[str, Any], other: dict[str, Any]) -> list[str]:
    """Differences between two report.json rows (metrics exactly; seconds ignored)."""
    problems = []
    a, b = ref.get("rows", []), other.get("rows", [])
    if [r.get("method") for r in a] != [r.get("method") for r in b]:
        return [f"report rows differ: {[r.get('method') for r in a]} vs {[r.get('method') for r in b]}"]
    for ra, rb in zip(a, b):
        for k in METRIC_KEYS:
            if ra.get(k) != rb.get(k):
                problems.append(f"row {ra.get('method')!r}: {k} {ra.get(k)!r} (reference) != {rb.get(k)!r}")
    return problems


def _without_seconds(obj: Any) -> Any:
    """``obj`` without the keys that hold wall times ("seconds", "*_seconds") at any depth."""
    if isinstance(obj, dict):
        return {k: _without_seconds(v) for k, v in obj.items() if k != "seconds" and not k.endswith("_seconds")}
    if isinstance(obj, list):
        return [_without_seconds(v) for v in obj]
    return obj


def _digest(path: Path) -> str:
    if path.suffix == ".json":  # evaluation seconds differ between runs; metrics must not
        data = _without_seconds(json.loads(path.read_text()))
        return hashlib.sha1(json.dumps(data, sort_keys=True).encode()).hexdigest()
    return hashlib.sha1(path.read_bytes()).hexdigest()


ARTIFACT_GLOBS = ("init_*/*.ply", "init_*/init_report.json", "baseline_sparse/*.ply", "model_*.ply",
                  "cache/round_*/*/*.png", "cache/round_*/*/confidence.npz", "eval/*/metrics.json")


def compare_artifacts(ref: Path, other: Path) -> list[str]:
    """Artifacts whose content differs between two run folders (in pipeline order)."""
    problems = []
    for pattern in ARTIFACT_GLOBS:
        names = sorted({p.relative_to(ref) for p in ref.glob(pattern)} | {p.relative_to(other) for p in other.glob(pattern)})
        for rel in names:
            a, b = ref / rel, other / rel
            if not (a.is_file() and b.is_file()):
                problems.append(f"{rel}: only in {'reference' if a.is_file() else 'killed run'}")
            elif pattern.endswith("init_report.json"):
                continue  # holds timings
            elif _digest(a) != _digest(b):
                problems.append(f"{rel}: content differs")
    return problems


def leftovers(run: Path) -> list[str]:
    """Partial or temporary files and set-aside cache entries anywhere under ``run``."""
    found = []
    for p in sorted(run.rglob("*")):
        rel = p.relative_to(run)
        if any(part.startswith(".") for part in rel.parts) or ".tmp." in p.name or ".old." in p.name:
            found.append(str(rel))
    for d in ("cache/corrupt", "cache/stale"):
        if (run / d).exists():
            found.append(d)
    return sorted(set(found))


def _entry_cameras(run: Path) -> dict[str, Any]:
    out = {}
    for meta in sorted(run.glob("cache/round_*/*/meta.json")):
        m = json.loads(meta.read_text())
        out[str(meta.parent.relative_to(run))] = m.get("trajectory", {}).get("cameras")
    return out


def check_config_change(killed: Path, fresh: Path, settings: dict[str, Any], change: dict[str, Any],
                        timeout_s: float) -> tuple[list[str], dict[str, Any]]:
    """Rerun ``killed`` with ``change`` applied: it must be refused (exit 2, nothing changed) or
    its cache must equal a fresh run's of the changed config (no stale entry served)."""
    before = {str(p.relative_to(killed)): p.stat().st_mtime_ns for p in killed.rglob("*") if p.is_file()}
    changed = {**settings, **change}
    att = launch(killed, changed, timeout_s=timeout_s)
    info: dict[str, Any] = {"change": change, "returncode": att.returncode, "message": att.stderr_tail.strip()[-400:]}
    if att.returncode == 2:  # InputError through the CLI handler: exit 2
        after = {str(p.relative_to(killed)): p.stat().st_mtime_ns for p in killed.rglob("*") if p.is_file()}
        info["outcome"] = "refused"
        if "error:" not in att.stderr_tail:
            return [f"config-change run failed (exit {att.returncode}) without a refusal: {att.stderr_tail[-400:]}"], info
        if after != before:
            touched = sorted(k for k in set(before) | set(after) if before.get(k) != after.get(k))
            return [f"refused config change still modified {touched[:5]}"], info
        if len(att.stderr_tail.strip().splitlines()) != 1:
            return [f"refusal is not one line: {att.stderr_tail.strip()[-400:]!r}"], info
        return [], info
    if att.returncode != 0:
        return [f"config-change run failed with exit {att.returncode}: {att.stderr_tail[-400:]}"], info
    info["outcome"] = "recomputed"
    ref = launch(fresh, changed, timeout_s=timeout_s)
    if ref.returncode != 0:
        return [f"fresh run of the changed config failed: {ref.stderr_tail[-400:]}"], info
    a, b = _entry_cameras(fresh), _entry_cameras(killed)
    stale = sorted(k for k in a if a[k] != b.get(k))
    return ([f"stale cache entries served after the config change: {stale[:5]}"] if stale else []), info


# ---- the whole experiment ----------------------------------------------------------------------
def run_experiment(out: Path, kills: int, settings: dict[str, Any], seed: int = 0,
                   change: dict[str, Any] | None = None, timeout_s: float = 1800.0,
                   targets: list[tuple[str, float]] | None = None, references: int = 2,
                   log=print) -> dict[str, Any]:
    """Steps 1-3 of the module doc; returns a JSON-able result with ``ok`` and ``problems``.

    targets: (stage, fraction of its reference duration) per kill, in pipeline order, instead
    of ``kills`` random points; the test uses it to place its few kills where resuming is
    hardest (training before and after its first checkpoint).
    references: uninterrupted runs before the kills. The first one also compiles the numba
    kernels (cached on disk) and warms the file cache, which would stretch its stage times and
    make kills land late, so the timeline is the last one's; all must agree exactly (a
    difference there is nondeterminism that has nothing to do with resuming)."""
    out = Path(out)
    rng = random.Random(seed)
    ref_dirs = [out / f"reference_{i}" for i in range(max(1, references))]
    ref_dir, run_dir = ref_dirs[-1], out / "killed"
    for d in (*ref_dirs, run_dir, out / "fresh_changed"):
        if d.exists():
            raise SystemExit(f"{d} exists; pass an empty --out")
    problems: list[str] = []
    for d in ref_dirs:
        ref = launch(d, settings, timeout_s=timeout_s)
        if ref.returncode != 0:
            raise SystemExit(f"the reference run {d} failed (exit {ref.returncode}):\n{ref.stderr_tail}")
        log(f"{d.name}: {ref.wall_s:.1f} s wall")
    for d in ref_dirs[:-1]:
        found = compare_reports(json.loads((d / "report.json").read_text()),
                                json.loads((ref_dir / "report.json").read_text())) + compare_artifacts(d, ref_dir)
        problems += [f"uninterrupted runs differ ({d.name} vs {ref_dir.name}): {p}" for p in found]
    order = _stages(ref_dir)
    durations = stage_durations(ref.timeline)
    log("stages " + ", ".join(f"{k} {v:.1f}s" for k, v in durations.items()))

    attempts: list[Attempt] = []
    if targets is not None:
        missing = [t for t, _ in targets if t not in durations]
        if missing:
            raise SystemExit(f"kill targets {missing} are not stages of this run ({order})")
        plan = [(t, f * durations[t]) for t, f in sorted(targets, key=lambda tf: order.index(tf[0]))]
        kills = len(plan)
    else:
        plan = plan_kills(durations, kills, rng)
    backup = out / "killed.before_attempt"
    for stage, delay in plan:
        if stage in _stages(run_dir):  # an earlier kill landed past it: too late to hit this stage
            log(f"kill target {stage}: already finished, skipped")
            continue
        for attempt in range(OVERSHOOT_RETRIES + 1):
            if run_dir.exists():  # the folder as this kill finds it, to retry from if the kill overshoots
                shutil.rmtree(backup, ignore_errors=True)
                shutil.copytree(run_dir, backup)
            att = launch(run_dir, settings, kill_stage=stage, order=order, delay_s=delay, timeout_s=timeout_s)
            late = att.killed_after_s is None or att.landed is None or order.index(att.landed) > order.index(stage)
            if not late or attempt == OVERSHOOT_RETRIES:
                break
            # the stage ran faster than in the reference (load varies): put the folder back as it
            # was and kill earlier; the discarded attempt only finished stages normally
            log(f"  kill in {stage} +{delay:.2f}s overshot to {att.landed or 'the end'}; retrying at +{delay / 2:.2f}s")
            shutil.rmtree(run_dir)
            if backup.exists():
                shutil.copytree(backup, run_dir)
            delay /= 2
        shutil.rmtree(backup, ignore_errors=True)
        attempts.append(att)
        if att.killed_after_s is None:
            log(f"kill {len(attempts)}: the run ended (exit {att.returncode}) before the kill in {stage}")
            if att.returncode not in (0, None):
                raise SystemExit(f"a resumed run failed (exit {att.returncode}):\n{att.stderr_tail}")
            break
        log(f"kill {len(attempts)}: target {stage} +{delay:.2f}s, killed {att.killed_after_s:.2f}s after launch "
            f"in {att.landed or 'the report'}")
    final = launch(run_dir, settings, timeout_s=timeout_s)
    if final.returncode != 0:
        problems.append(f"the final resume failed (exit {final.returncode}): {final.stderr_tail[-600:]}")
    landed = [a.landed or "report" for a in attempts if a.killed_after_s is not None]
    missed = [s for s in order if s not in landed]
    if len(landed) < kills:
        problems.append(f"only {len(landed)} of {kills} kills happened")
    if kills >= len(order) and missed:
        problems.append(f"no kill landed in {missed}")
    ref_report = json.loads((ref_dir / "report.json").read_text())
    if final.returncode == 0:
        problems += compare_reports(ref_report, json.loads((run_dir / "report.json").read_text()))
        problems += compare_artifacts(ref_dir, run_dir)
    problems += [f"left behind: {p}" for p in leftovers(run_dir)]
    change_info: dict[str, Any] = {}
    if change:
        found, change_info = check_config_change(run_dir, out / "fresh_changed", settings, change, timeout_s)
        problems += found
    result = {
        "ok": not problems, "problems": problems, "kills": len(landed), "kills_per_stage":
            {s: landed.count(s) for s in dict.fromkeys(order + ["report"]) if landed.count(s)},
        "stages": order, "references": len(ref_dirs), "reference_wall_s": ref.wall_s, "reference_stage_s": durations,
        "attempts": [{"target": a.target, "landed": a.landed, "killed_after_s": a.killed_after_s,
                      "wall_s": a.wall_s} for a in attempts],
        "final_resume_wall_s": final.wall_s, "settings": settings, "seed": seed, "config_change": change_info,
        "metric_tolerance": 0.0,
    }
    return result


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", required=True, help="empty scratch folder (reference_<i>/, killed/, fresh_changed/)")
    p.add_argument("--kills", type=int, default=10, help="SIGKILLs (>= the number of stages puts one in each)")
    p.add_argument("--seed", type=int, default=0, help="seed of the kill points")
    p.add_argument("--fast", action="store_true", help="the test's smaller settings instead of the tiny pipeline's")
    p.add_argument("--set", action="append", default=[], metavar="KEY=JSON", help="extra pipeline settings")
    p.add_argument("--change", action="append", default=None, metavar="KEY=JSON",
                   help="the config change of the stale-cache check (default trajectories.seed=1)")
    p.add_argument("--references", type=int, default=2,
                   help="uninterrupted runs first (the first warms caches; all must agree); default 2")
    p.add_argument("--json", help="write the result here")
    args = p.parse_args(argv)
    settings = dict(FAST_SETTINGS if args.fast else TINY_SETTINGS)
    for item in args.set:
        k, _, v = item.partition("=")
        settings[k] = json.loads(v)
    change = DEFAULT_CHANGE if args.change is None else {
        k: json.loads(v) for k, _, v in (c.partition("=") for c in args.change)}
    t0 = time.perf_counter()
    result = run_experiment(Path(args.out), args.kills, settings, args.seed, change, references=args.references)
    result["total_wall_s"] = time.perf_counter() - t0
    result["load_average"] = os.getloadavg()
    text = json.dumps(result, indent=2)
    if args.json:
        Path(args.json).write_text(text + "\n")
    print(text)
    return 0 if result["ok"] else 1


if __name__ == "__main__":
    sys.exit(main())
