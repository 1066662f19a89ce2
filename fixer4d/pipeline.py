"""The whole method, stage by stage, resumable: poses -> init -> stage 1 -> (restore -> refine) x R -> evaluate.

``run_pipeline(config, run_dir)`` writes everything into one run folder (DESIGN.md §3):

    config.json               the PipelineConfig (every stage's dataclass)
    init_mvs/, init_sparse/   per-frame clouds + init_report.json
    model_stage1.ply          stage 1 from the MVS init ("STGS w/ MVS")
    baseline_sparse/          stage 1 from the sparse COLMAP init ("STGS w/ COLMAP")
    cache/round_<r>/          restored trajectory clips (pseudo-targets)
    model_final.ply           after stage 2 ("Full")
    eval/<method>/            metrics.json + side-by-side PNGs per report row
    report.md, report.json    the paper's Table 2 rows with per-stage seconds
    stages.json               seconds per finished stage (how a resumed run keeps its timings)

Each stage is skipped when its output exists, so a killed run resumes where it stopped (the
trainer also resumes mid-stage from its checkpoints).
"""
from __future__ import annotations

import copy
import dataclasses
import json
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np
import torch

from fixer4d import atomic
from fixer4d.errors import InputError
from fixer4d.geometry.camera import Camera

ROW_NAMES = ("STGS w/ COLMAP", "STGS w/ MVS", "Restoration (init)", "Full", "Restoration (refined)")


# ---------------------------------------------------------------------------------------------
# configuration
# ---------------------------------------------------------------------------------------------
@dataclass
class SceneConfig:
    """Which scene and how much of it: a source for ``fixer4d.scene.load_scene``."""

    source: str = "demo"
    scale: float = 1.0
    frame_range: list[int] | None = None


@dataclass
class TrajectoryConfig:
    """The novel trajectories rendered and restored in stage 2 (DESIGN.md §4, Eq. 3)."""

    frames: int = 6            # cameras per trajectory clip
    amplitude: float | None = None  # arc amplitude A; None = drawn from the seeded range
    arcs: bool = True          # add the arcs on the two diagonal pairs
    seed: int = 0
    time_stride: int = 5       # restore clips every `time_stride` frames of the video


@dataclass
class PipelineConfig:
    """Every knob of a run; ``stage1``/``stage2``/``init``/``restorer`` hold those stages' own
    config dataclasses as dicts (their defaults live beside the stage)."""

    scene: SceneConfig = field(default_factory=SceneConfig)
    init: dict[str, Any] = field(default_factory=lambda: {"method": "mvs"})
    baseline_sparse: bool = True   # also train from the sparse init for the "STGS w/ COLMAP" row
    # Sized so that `fixer4d run demo` (two stage-1 trainings, R = 2 restoration rounds and five
    # evaluations) ends in about 10 minutes on 2 CPU cores; raise them for quality.
    stage1: dict[str, Any] = field(default_factory=lambda: {"iterations": 500, "init_max_points": 25_000,
                                                             "max_gaussians": 30_000})
    stage2: dict[str, Any] = field(default_factory=lambda: {"rounds": 2, "refresh_every": 150})
    trajectories: TrajectoryConfig = field(default_factory=TrajectoryConfig)
    restorer: dict[str, Any] = field(default_factory=dict)
    # Point clouds from every `init_frame_stride`-th frame: each Gaussian's temporal extent
    # starts at the gap between clouds (model.from_points), so a stride trades init time for
    # nothing but a longer initial lifetime. Both inits use the same frames.
    init_frame_stride: int = 4
    eval_stride: int = 5
    restoration_rows: bool = True  # evaluate restored renders at the held-out cameras
    # [B2 effects] effects by evidence (fixer4d.model.effects.EffectsConfig as a dict: mode
    # auto | all | static + forced overrides); applies to the decomposed MVS init.
    effects: dict[str, Any] = field(default_factory=lambda: {"mode": "auto"})
    seed: int = 0

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "PipelineConfig":
        d = copy.deepcopy(d)
        return cls(scene=SceneConfig(**d.pop("scene", {})), trajectories=TrajectoryConfig(**d.pop("trajectories", {})), **d)


def apply_overrides(config: PipelineConfig, overrides: dict[str, Any], relative: set[str] | None = None) -> PipelineConfig:
    """Return a copy with dotted-key overrides applied (``"stage1.iterations": 800``).

    Keys in ``relative`` multiply the current value (or the stage default) instead of replacing
    it, so a sweep can say "half the iterations" for any scene.
    """
    relative = relative or set()
    d = config.to_dict()
    free_sections = {"init", "stage1", "stage2", "restorer"}  # dicts of a stage's own config
    for key, value in overrides.items():
        parts = key.split(".")
        node = d
        for depth, p in enumerate(parts[:-1]):
            if not isinstance(node.get(p), dict):
                if parts[0] in free_sections and depth > 0 or p in free_sections:
                    node[p] = {}
                else:
                    raise InputError(f"override {key!r}: no section {p!r} in the pipeline config "
                                     f"(sections: {sorted(k for k, v in d.items() if isinstance(v, dict))})")
            node = node[p]
        leaf = parts[-1]
        if key in relative:
            base = node.get(leaf, _stage_default(parts))
            if base is None:
                raise InputError(f"override {key!r}: relative knob without a base value")
            value = type(base)(round(base * value)) if isinstance(base, int) else base * value
        node[leaf] = value
    return PipelineConfig.from_dict(d)


def parse_set_overrides(items: list[str]) -> dict[str, Any]:
    """``--set KEY=VALUE`` arguments -> {dotted key: value}; values are JSON where they parse
    (numbers, lists, true/false), strings otherwise."""
    out: dict[str, Any] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise InputError(f"--set {item!r}: expected KEY=VALUE, e.g. stage1.iterations=800")
        try:
            out[key] = json.loads(value)
        except json.JSONDecodeError:
            out[key] = value
    return out


def _stage_default(parts: list[str]) -> Any:
    """The default value of a stage config field named by a dotted path (``init.mvs.planes``)."""
    section = parts[0]
    if section == "stage1":
        from fixer4d.train.config import Stage1Config as cls
    elif section == "stage2":
        from fixer4d.train.config import Stage2Config as cls
    elif section == "init":
        from fixer4d.init import InitConfig as cls
    elif section == "restorer":
        from fixer4d.restore.reference_warp import ReferenceWarpConfig as cls
    else:
        return None
    node: Any = cls()
    for p in parts[1:]:
        node = getattr(node, p, None)
    return node


# ---------------------------------------------------------------------------------------------
# small helpers
# ---------------------------------------------------------------------------------------------
class StageTimes:
    """Seconds per stage, persisted in RUN/stages.json so a resumed run reports every stage."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.seconds: dict[str, float] = json.loads(path.read_text()) if path.exists() else {}

    def done(self, name: str) -> bool:
        return name in self.seconds

    def record(self, name: str, seconds: float) -> None:
        self.seconds[name] = float(seconds)
        atomic.write_json(self.path, self.seconds)

    def get(self, *names: str) -> float:
        return float(sum(self.seconds.get(n, 0.0) for n in names))


class StageCache:
    """Finished stage outputs shared between runs, e.g. the variants of a study.

    An output is keyed by everything it depends on (scene, init settings, frames, stage-1
    settings). A run that needs an output already computed copies it and records the seconds
    it originally took, so every variant still reports the full cost of its configuration.
    """

    def __init__(self, root: str | Path) -> None:
        self.root = Path(root)

    @staticmethod
    def key(*parts: Any) -> str:
        import hashlib

        return hashlib.sha1(json.dumps(parts, sort_keys=True, default=str).encode()).hexdigest()[:16]

    def fetch(self, key: str, dest: Path) -> float | None:
        """Copy the stored output into ``dest`` (a folder); its original seconds, or None."""
        import shutil

        entry = self.root / key
        if not (entry / "done.json").exists():
            return None
        shutil.copytree(entry / "data", dest, dirs_exist_ok=True)
        return float(json.loads((entry / "done.json").read_text())["seconds"])

    def store(self, key: str, files: list[Path], seconds: float) -> None:
        """Store files and folders (copied under their names) as the output for ``key``."""
        import shutil

        with atomic.atomic_dir(self.root / key) as tmp:
            (tmp / "data").mkdir()
            for f in files:
                if f.is_dir():
                    shutil.copytree(f, tmp / "data" / f.name)
                else:
                    shutil.copy2(f, tmp / "data" / f.name)
            (tmp / "done.json").write_text(json.dumps({"seconds": seconds}))


def load_scene_from_config(sc: SceneConfig):
    from fixer4d.scene import load_scene

    return load_scene(sc.source, scale=sc.scale, frame_range=None if sc.frame_range is None else tuple(sc.frame_range))


def render_views(model, cameras: list[Camera], t: float, backend: str = "auto",
                 background: torch.Tensor | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Render ``model`` at time ``t`` from every camera: rgb (F,H,W,3), depth (F,H,W), alpha (F,H,W)."""
    from fixer4d.render.api import render

    rgbs, depths, alphas = [], [], []
    with torch.no_grad():
        for cam in cameras:
            snap = model.at(t, camera_center=cam.center)
            out = render(snap, cam, background=background, backend=backend)
            rgbs.append(out.rgb.clamp(0, 1).numpy())
            depths.append(out.depth.numpy())
            alphas.append(out.alpha.numpy())
    return np.stack(rgbs).astype(np.float32), np.stack(depths).astype(np.float32), np.stack(alphas).astype(np.float32)


def make_request(model, scene, cameras: list[Camera], frame: int, ref_ids: tuple[int, int], *,
                 backend: str = "auto", trajectory: dict[str, Any] | None = None):
    """Render a clip and everything the restorer needs at the references (restorers never render)."""
    from fixer4d.restore.base import RestoreRequest

    t = scene.time(frame)
    rgb, depth, alpha = render_views(model, cameras, t, backend)
    ref_cams = [scene.cameras[i] for i in ref_ids]
    _, ref_depth, ref_alpha = render_views(model, ref_cams, t, backend)
    extra_ids = [i for i in scene.train_ids if i not in ref_ids]
    extra_cams = [scene.cameras[i] for i in extra_ids]
    _, extra_depth, _ = render_views(model, extra_cams, t, backend) if extra_ids else (None, [], None)
    return RestoreRequest(
        rgb=rgb, depth=depth, alpha=alpha, cameras=list(cameras), time=t, frame=frame,
        ref_images=[scene.frame(frame, i) for i in ref_ids], ref_cameras=ref_cams,
        ref_depths=list(ref_depth), ref_alphas=list(ref_alpha),
        extra_images=[scene.frame(frame, i) for i in extra_ids] or None, extra_cameras=extra_cams or None,
        extra_depths=list(extra_depth) or None, trajectory=trajectory or {})


def build_restorer(settings: dict[str, Any], weights_dir: Path | None = None):
    # [issue 12, helper C] the restorer is a choice: settings = RestoreConfig dict (kind learned |
    # warp | cogvideo; flat ReferenceWarpConfig keys still mean warp settings)
    from fixer4d.restore.config import RestoreConfig, build_restorer as build

    return build(RestoreConfig.from_dict(settings), weights_dir)


def _check_restorer(config: "PipelineConfig") -> None:
    # [issue 12, helper C] validate the restorer settings; cogvideo must be runnable here
    from fixer4d.restore.config import RestoreConfig

    rc = RestoreConfig.from_dict(config.restorer)
    if rc.kind == "cogvideo":
        build_restorer(config.restorer)


def _scene_restorer(scene, clouds, config: "PipelineConfig", run_dir: Path, times: "StageTimes", progress: bool,
                    model=None):
    # [issue 12, helper C] the learned restorer is trained (leave-one-camera-out, train cameras
    # only) into RUN/restorer before its first use; other kinds are just built
    from fixer4d.restore.config import RestoreConfig

    rc = RestoreConfig.from_dict(config.restorer)
    if rc.kind != "learned":
        return build_restorer(config.restorer, run_dir / "restorer")
    from fixer4d.train.restorer_pairs import train_scene_restorer

    t0 = time.perf_counter()
    restorer = train_scene_restorer(scene, clouds, stage1_config(config.stage1, progress), run_dir / "restorer", rc,
                                    progress=progress, model=model)
    if not times.done("restorer"):
        times.record("restorer", time.perf_counter() - t0)
    return restorer


def scene_trajectories_for(scene, tc: TrajectoryConfig):
    """The 6 pair trajectories (+ arcs) of the scene's train cameras; pairs are mapped from
    train-list indices to scene camera indices."""
    from fixer4d.geometry.trajectory import scene_trajectories

    trajs = scene_trajectories(scene.train_cameras, tc.frames, amplitude=tc.amplitude, arcs=tc.arcs, seed=tc.seed)
    return [(tr, (scene.train_ids[tr.pair[0]], scene.train_ids[tr.pair[1]])) for tr in trajs]


def make_refresh_callback(run_dir: str | Path, scene, config: PipelineConfig, *, progress: bool = True,
                          backend: str = "auto") -> Callable[[Any, int], None]:
    """The stage-2 cache refresh: render every trajectory at every restored timestamp with the
    current model, restore the clips, write them to RUN/cache/round_<r>. Complete entries of a
    round are reused (a resumed run does not redo them)."""
    from fixer4d.restore.cache import RestoreCache

    cache = RestoreCache(Path(run_dir) / "cache")
    cache.clean_temporary()  # leftovers of a killed write; complete entries are reused below
    restorer = build_restorer(config.restorer, Path(run_dir) / "restorer")  # [issue 12, helper C]
    trajectories = scene_trajectories_for(scene, config.trajectories)
    frames = list(range(0, scene.num_frames, max(1, config.trajectories.time_stride)))

    def refresh(model, round_index: int) -> None:
        from tqdm.auto import tqdm

        todo = [(f, tr, ids) for f in frames for tr, ids in trajectories]
        bar = tqdm(todo, desc=f"restore round {round_index}", unit="clip", disable=not progress, leave=False)
        for f, tr, ids in bar:
            key = cache.key(f, ids[0], ids[1], tr.arc_index)
            if cache.has(round_index, key):
                continue
            traj_meta = {"name": tr.name, "pair": list(ids), "amplitude": float(tr.amplitude), "arc_index": tr.arc_index}
            req = make_request(model, scene, tr.cameras, f, ids, backend=backend, trajectory=traj_meta)
            res = restorer.restore(req)
            cache.write(round_index, key, req, res, {"restorer": restorer.name, "restorer_settings": restorer.settings(),
                                                     "restorer_kind": config.restorer.get("kind", "warp"),  # [issue 12, C]
                                                     "model_gaussians": int(model.num_gaussians)})

    return refresh


def restoration_render_fn(model, scene, restorer, backend: str = "auto") -> Callable[[Camera, float], np.ndarray]:
    """A render function for evaluation whose images are *restored* renders.

    For a held-out camera h, the trajectory passes through it: the two train cameras nearest to
    h are the references, the clip is (midpoint ref_a..h, h, midpoint h..ref_b) and the restored
    middle frame is returned (the "restoration" rows of the paper's Table 2).
    """
    from fixer4d.geometry.trajectory import interpolate_pair

    def fn(camera: Camera, t: float) -> np.ndarray:
        frame = int(round(t * scene.num_frames))
        d = [np.linalg.norm(scene.cameras[i].center - camera.center) for i in scene.train_ids]
        order = np.argsort(d)
        ids = (scene.train_ids[order[0]], scene.train_ids[order[1]])
        a, b = scene.cameras[ids[0]], scene.cameras[ids[1]]
        cams = [interpolate_pair(a, camera, np.array([0.5]), 0.0)[0], camera,
                interpolate_pair(camera, b, np.array([0.5]), 0.0)[0]]
        req = make_request(model, scene, cams, frame, ids, backend=backend,
                           trajectory={"name": f"through-{camera.name}", "pair": list(ids), "amplitude": 0.0})
        return restorer.restore(req).rgb[1]

    return fn


# ---------------------------------------------------------------------------------------------
# the pipeline
# ---------------------------------------------------------------------------------------------
def _init_clouds(scene, run_dir: Path, init_cfg: dict[str, Any], method: str, times: StageTimes, progress: bool,
                 frame_stride: int, cache: StageCache | None, cache_key: str):
    from fixer4d.init import InitConfig, load_frame_clouds, run_init

    out = run_dir / f"init_{method}"
    stage = f"init_{method}"
    if times.done(stage) and (out / "init_report.json").exists():
        return _decomposed_or(out, load_frame_clouds(out))
    if cache is not None and (seconds := cache.fetch(cache_key, out)) is not None:
        times.record(stage, seconds)
        return _decomposed_or(out, load_frame_clouds(out))
    cfg = InitConfig.from_dict({k: v for k, v in init_cfg.items() if k != "method"})
    t0 = time.perf_counter()
    frames = list(range(0, scene.num_frames, max(1, frame_stride)))
    clouds, _report = run_init(scene, method, out, frames=frames, config=cfg, progress=progress)
    # [A2 fault injection] Train from the clouds as stored (colours are uint8 on disk): a resumed
    # run loads them from disk, so the in-memory float colours made stage 1 differ after a kill.
    clouds = load_frame_clouds(out)
    times.record(stage, time.perf_counter() - t0)
    if cache is not None:
        cache.store(cache_key, [out / p.name for p in out.iterdir()], times.seconds[stage])
    return _decomposed_or(out, clouds)


def _decomposed_or(out: Path, clouds):
    """[B2 effects] The DecomposedInit of an init folder when it has one, else its clouds."""
    from fixer4d.init.decompose import DecomposedInit, has_decomposed

    return DecomposedInit.load(out) if has_decomposed(out) else clouds


def stage1_config(stage1: dict[str, Any], progress: bool = True):
    """Stage1Config from the pipeline's stage1 dict: the 3DGS schedule scaled to its iterations,
    explicit keys winning."""
    from fixer4d.train.config import Stage1Config

    iterations = int(stage1.get("iterations", Stage1Config().iterations))
    return Stage1Config.for_iterations(iterations, **{k: v for k, v in stage1.items() if k != "iterations"},
                                       progress=progress)


def _stage1(scene, clouds, stage1: dict[str, Any], model_path: Path, times: StageTimes, stage: str, progress: bool,
            cache: StageCache | None, cache_key: str, effects: dict[str, Any] | None = None):
    from fixer4d.model.effects import EffectsConfig, effects_report
    from fixer4d.model.io import load_ply, save_ply
    from fixer4d.train.trainer import Trainer, model_from_init

    if times.done(stage) and model_path.exists():
        return load_ply(model_path)
    if cache is not None and (seconds := cache.fetch(cache_key, model_path.parent)) is not None:
        times.record(stage, seconds)
        return load_ply(model_path)
    cfg = stage1_config(stage1, progress)
    t0 = time.perf_counter()
    eff = EffectsConfig.from_dict(effects)  # [B2 effects] decided by evidence, recorded
    model, decision = model_from_init(clouds, scene, cfg, eff)
    trainer = Trainer(model, scene, cfg, run_dir=model_path.parent, effects=eff if decision is not None else None)
    trainer.resume()
    trainer.train()
    save_ply(trainer.model, model_path)
    atomic.write_json(model_path.parent / "model_effects.json", effects_report(trainer.model, decision, trainer.revisions))
    times.record(stage, time.perf_counter() - t0)
    if cache is not None:
        cache.store(cache_key, [model_path], times.seconds[stage])
    return trainer.model


def _evaluate(render_fn, scene, run_dir: Path, name: str, stride: int, seconds: dict[str, float],
              times: StageTimes, progress: bool) -> dict[str, Any]:
    from fixer4d.eval.evaluate import evaluate

    slug = name.lower().replace(" ", "-").replace("/", "").replace("(", "").replace(")", "")
    out = run_dir / "eval" / slug
    stage = f"eval:{slug}"
    if times.done(stage) and (out / "metrics.json").exists():
        return json.loads((out / "metrics.json").read_text())
    t0 = time.perf_counter()
    metrics = evaluate(render_fn, scene, out, frame_stride=stride, method_name=name, seconds=seconds, progress=progress)
    times.record(stage, time.perf_counter() - t0)
    return metrics


def _model_render_fn(model, backend: str = "auto") -> Callable[[Camera, float], np.ndarray]:
    def fn(camera: Camera, t: float) -> np.ndarray:
        return render_views(model, [camera], t, backend)[0][0]

    return fn


def run_pipeline(config: PipelineConfig, run_dir: str | Path, *, progress: bool = True,
                 stage_cache: str | Path | None = None) -> dict[str, Any]:
    """Run (or resume) the whole method; returns the report dict (also RUN/report.json).

    stage_cache: a folder shared by several runs (a study) where finished inits and stage-1
    models are kept and reused by runs whose settings match (see StageCache).
    """
    run_dir = Path(run_dir)
    _check_restorer(config)  # [issue 12, helper C] a bad kind or an unavailable cogvideo stops before any work
    run_dir.mkdir(parents=True, exist_ok=True)
    cfg_path = run_dir / "config.json"
    if cfg_path.exists():
        previous = json.loads(cfg_path.read_text()).get("pipeline")
        if previous is not None and previous != json.loads(json.dumps(config.to_dict())):
            raise InputError(f"{run_dir}: holds a run with a different configuration; use another --out "
                             "or delete the folder to start over")
    atomic.write_json(cfg_path, {"scene": dataclasses.asdict(config.scene), "pipeline": config.to_dict()})
    torch.manual_seed(config.seed)
    times = StageTimes(run_dir / "stages.json")
    scene = load_scene_from_config(config.scene)
    if progress:
        print(f"[fixer4d] {scene.describe()}", flush=True)
    backend = config.stage1.get("backend", "auto")
    rows: list[dict[str, Any]] = []

    def row(name: str, metrics: dict[str, Any], seconds: float | None) -> None:
        m = metrics["mean"]
        rows.append({"method": name, "psnr": m["psnr"], "dssim1": m["dssim1"], "dssim2": m["dssim2"],
                     "lpips": m.get("lpips"), "seconds": seconds})
        _write_report(run_dir, config, scene, rows, times)

    method = config.init.get("method", "mvs")
    cache = StageCache(stage_cache) if stage_cache is not None else None
    scene_key = dataclasses.asdict(config.scene)

    def init_key(m: str) -> str:
        return StageCache.key("init", m, scene_key, {k: v for k, v in config.init.items() if k != "method"},
                              config.init_frame_stride)

    def stage1_key(m: str) -> str:
        return StageCache.key("stage1", init_key(m), config.stage1, config.seed, config.effects)  # [B2 effects]
    # -- baseline: STGS from the sparse (COLMAP) init -----------------------------------------
    if config.baseline_sparse and method != "sparse":
        sparse = _init_clouds(scene, run_dir, config.init, "sparse", times, progress, config.init_frame_stride,
                              cache, init_key("sparse"))
        base_model = _stage1(scene, sparse, config.stage1, run_dir / "baseline_sparse" / "model_stage1.ply", times,
                             "stage1_sparse", progress, cache, stage1_key("sparse"))
        secs = times.get("init_sparse", "stage1_sparse")
        m = _evaluate(_model_render_fn(base_model, backend), scene, run_dir, ROW_NAMES[0], config.eval_stride,
                      {"prep": times.get("init_sparse"), "train": times.get("stage1_sparse")}, times, progress)
        row(ROW_NAMES[0], m, secs)
        del base_model

    # -- ours: dense (MVS) init + stage 1 -------------------------------------------------------
    clouds = _init_clouds(scene, run_dir, config.init, method, times, progress, config.init_frame_stride,
                          cache, init_key(method))
    model = _stage1(scene, clouds, config.stage1, run_dir / "model_stage1.ply", times, "stage1", progress,
                    cache, stage1_key(method), config.effects)
    init_name = ROW_NAMES[1] if method != "sparse" else ROW_NAMES[0]
    m = _evaluate(_model_render_fn(model, backend), scene, run_dir, init_name, config.eval_stride,
                  {"prep": times.get(f"init_{method}"), "train": times.get("stage1")}, times, progress)
    secs_stage1 = times.get(f"init_{method}", "stage1")
    row(init_name, m, secs_stage1)
    final_metrics = m

    restorer = _scene_restorer(scene, clouds, config, run_dir, times, progress, model)  # [issue 12, helper C]
    secs_restorer = times.get("restorer")  # [issue 12, helper C] training the learned restorer counts
    if config.restoration_rows:
        m = _evaluate(restoration_render_fn(model, scene, restorer, backend), scene, run_dir, ROW_NAMES[2],
                      config.eval_stride, {"prep": times.get(f"init_{method}"), "train": times.get("stage1")}, times, progress)
        row(ROW_NAMES[2], m, secs_stage1 + secs_restorer + times.get("eval:restoration-init"))

    # -- stage 2: (restore -> refine) x R --------------------------------------------------------
    rounds = int(config.stage2.get("rounds", 2))
    if rounds > 0:
        model = _stage2(scene, model, run_dir, config, times, progress, backend)
        secs_full = secs_stage1 + secs_restorer + times.get("stage2")
        m = _evaluate(_model_render_fn(model, backend), scene, run_dir, ROW_NAMES[3], config.eval_stride,
                      {"prep": times.get(f"init_{method}"), "train": times.get("stage1", "stage2")}, times, progress)
        row(ROW_NAMES[3], m, secs_full)
        final_metrics = m
        if config.restoration_rows:
            m = _evaluate(restoration_render_fn(model, scene, restorer, backend), scene, run_dir, ROW_NAMES[4],
                          config.eval_stride, {"prep": times.get(f"init_{method}"), "train": times.get("stage1", "stage2")},
                          times, progress)
            row(ROW_NAMES[4], m, secs_full + times.get("eval:restoration-refined"))
    atomic.write_json(run_dir / "metrics.json", final_metrics)
    return _write_report(run_dir, config, scene, rows, times)


def _stage2(scene, model, run_dir: Path, config: PipelineConfig, times: StageTimes, progress: bool, backend: str):
    from fixer4d.model.io import load_ply, save_ply
    from fixer4d.restore.cache import RestoreCache
    from fixer4d.train.config import Stage2Config
    from fixer4d.train.trainer import Trainer

    final = run_dir / "model_final.ply"
    if times.done("stage2") and final.exists():
        return load_ply(final)
    s1 = stage1_config(config.stage1, progress)
    s2 = Stage2Config(**config.stage2)
    t0 = time.perf_counter()
    refresh = make_refresh_callback(run_dir, scene, config, progress=progress, backend=backend)
    trainer = Trainer(model, scene, s1, run_dir=run_dir, stage2=s2, cache=RestoreCache(run_dir / "cache"),
                      refresh_cache=refresh)
    trainer.resume()
    trainer.train()
    save_ply(trainer.model, final)
    times.record("stage2", time.perf_counter() - t0)
    return trainer.model


def _restorer_line(run_dir: Path, config: PipelineConfig) -> str:
    # [issue 12, helper C] the report names the restorer and, for the learned one, its validation
    kind = config.restorer.get("kind", "warp")
    val = run_dir / "restorer" / "validation.json"
    if kind != "learned" or not val.exists():
        return f"Restorer: {kind}"
    v = json.loads(val.read_text())
    return (f"Restorer: learned (leave-one-camera-out validation on train camera {v['held_out_fold_camera']}: "
            f"render {v['psnr_render']:.2f} dB -> restored {v['psnr_learned']:.2f} dB, {v['gain_db']:+.2f} dB; warp "
            f"restorer {v['psnr_warp']:.2f} dB; {v['cpu_seconds']['total']:.0f} CPU s to train)")


def _fmt(value: float | None, digits: int) -> str:
    """Table cell: n/a for a missing value (LPIPS without weights; PSNR of an exact render)."""
    return "n/a" if value is None else f"{value:.{digits}f}"


def _write_report(run_dir: Path, config: PipelineConfig, scene, rows: list[dict[str, Any]], times: StageTimes) -> dict[str, Any]:
    report = {"rows": rows, "stage_seconds": times.seconds, "scene": scene.describe()}
    if (run_dir / "model_effects.json").exists():  # [B2 effects] the stage-1 model's effects and why
        report["model"] = json.loads((run_dir / "model_effects.json").read_text())
    atomic.write_json(run_dir / "report.json", report)
    lines = [f"# fixer4d report: {run_dir.name}", "", f"Scene: {scene.describe()}", "", _restorer_line(run_dir, config), "",
             "| Method | PSNR | DSSIM1 | DSSIM2 | LPIPS | Time (s) |", "|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['method']} | {_fmt(r['psnr'], 2)} | {_fmt(r['dssim1'], 4)} | {_fmt(r['dssim2'], 4)} | "
                     f"{_fmt(r['lpips'], 4)} | {_fmt(r['seconds'], 1)} |")
    lines += ["", "Seconds per stage:", "", "| Stage | Seconds |", "|---|---|"]
    lines += [f"| {k} | {v:.1f} |" for k, v in times.seconds.items()]
    atomic.write_text(run_dir / "report.md", "\n".join(lines) + "\n")
    return report


# ---------------------------------------------------------------------------------------------
# the study's entry point
# ---------------------------------------------------------------------------------------------
def run_variant(source: str, overrides: dict[str, Any], run_dir: str | Path, *, progress: bool = True,
                base: dict[str, Any] | None = None, stage_cache: str | Path | None = None) -> dict[str, Any]:
    """Run one study variant: the pipeline without the extra report rows, returning the final
    model's held-out metrics and its per-stage seconds.

    base: absolute overrides of the default configuration (the study's base); overrides: the
    variant's knobs, where the keys in ``study.RELATIVE_KNOBS`` multiply the base value.
    Variants sharing a ``stage_cache`` reuse each other's inits and stage-1 models (their
    recorded seconds still count).
    """
    from fixer4d.study import RELATIVE_KNOBS

    config = apply_overrides(default_config(source), {"baseline_sparse": False, "restoration_rows": False,
                                                      **(base or {})})
    config = apply_overrides(config, overrides, RELATIVE_KNOBS)
    report = run_pipeline(config, run_dir, progress=progress, stage_cache=stage_cache)
    final = report["rows"][-1]
    st = report["stage_seconds"]
    seconds = {"init": sum(v for k, v in st.items() if k.startswith("init_")), "stage1": st.get("stage1", 0.0),
               "stage2": st.get("stage2", 0.0)}
    seconds["total"] = sum(seconds.values())
    return {"psnr": final["psnr"], "dssim1": final["dssim1"], "dssim2": final["dssim2"], "lpips": final["lpips"],
            "seconds": seconds, "method": final["method"]}


def default_config(source: str) -> PipelineConfig:
    """The defaults for a source: the demo's are sized so `fixer4d run demo` ends in minutes on 2 cores."""
    return PipelineConfig(scene=SceneConfig(source=str(source)))
