"""``RunConfig``: every knob of a run, one typed tree, resolved and validated before anything is written.

    RunConfig
      scene         SceneConfig        which scene, scale, frame range
      init          InitConfig         (init/run.py) method mvs|sparse, plane sweep, fusion, ...
      model_terms   ModelTermsConfig   (model/terms.py) the model's optional terms: auto|all|static + forced switches
      training      TrainingConfig     (train/config.py) what every training of the run shares
      stage2        Stage2Config       (train/config.py) what stage 2 (restoration-guided refinement) adds
      trajectories  TrajectoryConfig   the novel trajectories restored in stage 2
      restorer      RestoreConfig      (restore/config.py) kind learned|warp|cogvideo + each kind's settings
      eval          EvalConfig         held-out evaluation
      segments      SegmentConfig      (pipeline/segments.py) long captures as temporal segments
      executor      ExecutorConfig     (pipeline/executors.py) where segments and restore jobs run
      self_check    SelfCheckConfig    (pipeline/self_check.py) stage 2 checked on a held-back train camera
      co_fields     CoFieldsConfig     (train/co_fields_config.py) a twin stage-1 field: co-pruning, undetermined weight
      baseline_sparse, init_frame_stride, seed

A config is built from the defaults, then an optional config file (a ``config.json`` of another
run or a hand-written partial one), then ``--set`` overrides (dotted keys). ``resolve`` does all
three and the validation; the resolved tree is what ``config.json`` stores, with
``FORMAT_VERSION``. A section under its former name (``RENAMED_SECTIONS``: a config.json of an
older run, an old config file, ``--set stage1.iterations=...`` or ``--set effects.mode=...``) still
loads, with a one-line note.
"""
from __future__ import annotations

import copy
import logging
from dataclasses import dataclass, field, fields, is_dataclass
from pathlib import Path
from typing import Any

from fixer4d.errors import InputError
from fixer4d.init.run import InitConfig
from fixer4d.model.terms import ModelTermsConfig
from fixer4d.pipeline import config_tree
from fixer4d.pipeline.executors import ExecutorConfig
from fixer4d.pipeline.segments import SegmentConfig
from fixer4d.pipeline.self_check import SelfCheckConfig
from fixer4d.restore.config import RestoreConfig
from fixer4d.train.co_fields_config import CoFieldsConfig
from fixer4d.train.config import TrainingConfig, Stage2Config

log = logging.getLogger("fixer4d.pipeline")

# Version of the run-folder layout and config.json schema. 1: the first landing (config.json
# {"scene", "pipeline"} or reconstruct's {"scene", "init", "stage1"}); 2: {"format_version",
# "config": RunConfig} plus per-stage keys in stages.json; 3: section "stage1" renamed "training";
# 4: section "effects" renamed "model_terms".
FORMAT_VERSION = 4

# Config sections renamed since they were written into run folders and config files: former name
# -> name. The stage keys hash the sections' contents, not their names, so a renamed section
# leaves every finished stage of an older run reusable.
RENAMED_SECTIONS = {"stage1": "training", "effects": "model_terms"}
# Settings whose default changed after run folders were saved without them: a run's config.json
# that lacks one was run with the value here, not with today's default.
SAVED_BEFORE = {("training", "fields"): 1, ("self_check", "fields"): 0}

# The paper's stage 2 (`--paper-stage2`): every pseudo-view pixel supervised by the restored
# frame with the restorer's confidence as weight, densified from every render, stage 2 run
# without asking, and the Restoration rows ungated.
PAPER_STAGE2 = {"stage2.pseudo_target": "restored", "stage2.pseudo_mask": "all", "stage2.densify_stats": "all",
                "self_check.enabled": False, "eval.gate_restoration": False}


@dataclass
class SceneConfig:
    """Which scene and how much of it: a source for ``fixer4d.scene.load_scene``."""

    source: str = "demo"
    scale: float = 1.0
    frame_range: tuple[int, int] | None = None  # half-open [a, b) of the source's frames
    # capture folders only (fixer4d.scene.capture): a calibration file (default: one beside the
    # videos, else the rig self-calibrated), per-camera start frames, cameras held out (default none)
    calibration: str | None = None
    offsets: dict[str, int] | None = None
    holdout: list[str] | None = None

    def __post_init__(self) -> None:
        if not self.scale > 0:
            raise InputError(f"scale must be > 0, got {self.scale}")
        if self.frame_range is not None and not 0 <= self.frame_range[0] < self.frame_range[1]:
            raise InputError(f"frame_range must be [a, b] with 0 <= a < b, got {list(self.frame_range)}")


@dataclass
class TrajectoryConfig:
    """The novel trajectories rendered and restored in stage 2 (docs/design.md §10, Eq. 3)."""

    frames: int = 6                  # cameras per trajectory clip
    amplitude: float | None = None   # arc amplitude A; None = drawn from the seeded range
    arcs: bool = True                # add the arcs on the two diagonal pairs
    seed: int = 0
    time_stride: int = 5             # restore clips every `time_stride` frames of the video
    # pseudo-views where the model is undetermined (pipeline.undetermined_views): this many extra
    # cameras per cache round, picked from an orbit pool around the rig by how much of their view
    # the train cameras leave unobserved, each reached by a path from its nearest train camera.
    # 0 = off: the pair paths and arcs only (docs/decisions/undetermined-views.md)
    undetermined_views: int = 0
    # the pool's elevations: the rig's own and this many degrees above and below it (a ring of
    # cameras leaves the views from above and below its plane to no camera)
    undetermined_elevation_deg: float = 20.0
    # the pool's radii in train-camera distances to the centre: theirs and this one (the viewer
    # starts 1.15x behind the rig; a viewer pulls back further to see the whole scene)
    undetermined_radius: float = 1.3
    # picks at least this far apart, seen from the centre: the visibility rule's full-observation
    # angle (restore.visibility, 25 degrees), so two picks do not look at the same surfaces
    undetermined_separation_deg: float = 25.0

    def __post_init__(self) -> None:
        if self.frames < 2:
            raise InputError(f"frames must be >= 2 (a clip needs both ends), got {self.frames}")
        if self.time_stride < 1:
            raise InputError(f"time_stride must be >= 1, got {self.time_stride}")
        if self.undetermined_views < 0:
            raise InputError(f"undetermined_views must be >= 0 (0 = off), got {self.undetermined_views}")
        if not 0.0 <= self.undetermined_elevation_deg < 90.0:
            raise InputError(f"undetermined_elevation_deg must be in [0, 90), got {self.undetermined_elevation_deg}")
        if not self.undetermined_radius > 0:
            raise InputError(f"undetermined_radius must be > 0, got {self.undetermined_radius}")
        if not 0.0 <= self.undetermined_separation_deg <= 180.0:
            raise InputError(f"undetermined_separation_deg must be in [0, 180], got {self.undetermined_separation_deg}")


@dataclass
class EvalConfig:
    """Held-out evaluation (every ``stride``-th frame of every held-out camera): the one set of
    evaluation settings. ``fixer4d.eval.evaluate.evaluate`` takes ``stride`` as its
    ``frame_stride`` and ``examples`` as its ``save_examples``; the other fields choose the rows."""

    stride: int = 5
    restoration_rows: bool = True    # also evaluate restored renders at the held-out cameras
    # also train and evaluate "STGS w/ MVS (matched iterations)": stage 1 continued as long as
    # stage 2 runs, without pseudo-views (shows that stage 2's gain is the restorer's)
    matched_row: bool = True
    examples: int = 3                # frames saved as render|gt|error PNGs per view
    # the "Blur (init)" baseline row: the stage-1 render low-passed by a Gaussian of this many
    # pixels, about the resampling blur of a bilinear warp (a restoration gain means something
    # only against the render itself and a plain blur of it)
    blur_sigma_px: float = 1.0
    # the Restoration rows use a restored frame only where the render is a hole or the train
    # cameras leave a pixel unobserved, there in proportion to the restorer's confidence
    # (pipeline.restoration.gate_restoration); false: the restorer's output as it is (the
    # paper's rows). Chosen on the validation cameras
    # by the worst case: gated 18.40 / 18.42 dB, ungated 18.79 / 18.18 against STGS w/ MVS 18.24 /
    # 18.42 (Panoptic 4/14, split c 2/12): ungated falls 0.24 dB under the render it starts from.
    gate_restoration: bool = True
    # what the gated rows fall back on where the restorer does not act: the render with its
    # unobserved pixels (holes included) filled from the observed ones around them, at or behind
    # their depth (restore.unobserved_fill); false: the render, its holes restored whatever the
    # confidence. Chosen on the validation cameras, Restoration (init) on Panoptic 4/14, split c
    # 2/12, demo_val: fill 21.11 / 20.88 / 25.41 dB (depth-blind: 20.97 / 20.87 / 25.42), render
    # 19.89 / 20.56 / 25.36 (docs/decisions/unobserved-fill.md).
    fill_unobserved: bool = True

    def __post_init__(self) -> None:
        if self.stride < 1:
            raise InputError(f"stride must be >= 1, got {self.stride}")
        if not self.blur_sigma_px > 0:
            raise InputError(f"blur_sigma_px must be > 0, got {self.blur_sigma_px}")


@dataclass
class RunConfig:
    """Every knob of a run (see the module docstring for the tree)."""

    scene: SceneConfig = field(default_factory=SceneConfig)
    init: InitConfig = field(default_factory=InitConfig)
    model_terms: ModelTermsConfig = field(default_factory=ModelTermsConfig)
    training: TrainingConfig = field(default_factory=TrainingConfig)
    stage2: Stage2Config = field(default_factory=Stage2Config)
    trajectories: TrajectoryConfig = field(default_factory=TrajectoryConfig)
    restorer: RestoreConfig = field(default_factory=RestoreConfig)
    eval: EvalConfig = field(default_factory=EvalConfig)
    segments: SegmentConfig = field(default_factory=SegmentConfig)
    executor: ExecutorConfig = field(default_factory=ExecutorConfig)
    self_check: SelfCheckConfig = field(default_factory=SelfCheckConfig)
    co_fields: CoFieldsConfig = field(default_factory=CoFieldsConfig)
    baseline_sparse: bool = True     # also train from the sparse init for the "STGS w/ COLMAP" row
    # Point clouds from every `init_frame_stride`-th frame (both inits use the same frames).
    init_frame_stride: int = 4
    seed: int = 0

    def __post_init__(self) -> None:
        if self.init_frame_stride < 1:
            raise InputError(f"init_frame_stride must be >= 1, got {self.init_frame_stride}")
        for key, value in _seeds(self):  # the random generators take whole numbers >= 0 only
            if isinstance(value, bool) or not isinstance(value, int) or value < 0:
                raise InputError(f"{key} must be a whole number >= 0, got {value!r}")

    def to_dict(self) -> dict[str, Any]:
        return config_tree.to_dict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any], source: str = "config") -> "RunConfig":
        """The config of tree ``d`` (sections under a former name renamed, with a note naming ``source``)."""
        return config_tree.build(cls, current_names(d, source))

    @property
    def init_method(self) -> str:
        return self.init.method


def _seeds(section: Any, prefix: str = "") -> list[tuple[str, Any]]:
    """(dotted key, value) of every ``seed`` field in the config tree under ``section``."""
    out = []
    for f in fields(section):
        value = getattr(section, f.name)
        if f.name == "seed":
            out.append((prefix + f.name, value))
        elif is_dataclass(value):
            out += _seeds(value, f"{prefix}{f.name}.")
    return out


def resolve(source: str | None = None, *, config_file: str | Path | dict[str, Any] | None = None,
            overrides: dict[str, Any] | None = None, relative: set[str] | None = None,
            defaults: dict[str, Any] | None = None) -> RunConfig:
    """Defaults <- config file <- overrides, validated in full; raises InputError naming the key.

    The defaults are the stage dataclasses' own (``RunConfig()``); ``defaults`` replaces them
    with a partial tree (a study's base).

    source: the scene (sets ``scene.source`` unless an override does). config_file: a path to a
    JSON config (a run's ``config.json`` or a partial tree) or the dict itself. relative: dotted
    keys whose override multiplies the value it replaces (a study's "half the iterations").
    """
    tree = current_names(copy.deepcopy(defaults or {}), "defaults")
    if config_file is not None:
        where = "--config" if isinstance(config_file, dict) else f"--config {config_file}"
        tree = config_tree.merge(tree, current_names(copy.deepcopy(_read_config_file(config_file)), where))
    if source is not None:
        # a scene folder or spec file is stored as an absolute path, so that the run folder's
        # config names the same scene from any working directory (refine, eval, the viewer)
        path = Path(str(source))
        config_tree.set_dotted(tree, "scene.source", str(path.resolve()) if path.exists() else str(source))
    relative = {_current_key(k) for k in relative or set()}
    overrides = {_current_key(k, note=True): v for k, v in (overrides or {}).items()}
    if "training.iterations" in overrides:
        # first, so that a schedule key given beside it wins over the derived one
        value = overrides.pop("training.iterations")
        if "training.iterations" in relative:
            value = _scaled(tree, "training.iterations", value)
        training = tree.get("training")
        if isinstance(training, dict) and isinstance(value, int) and not isinstance(value, bool):
            # a full config (a run's config.json, a study's base) writes its schedule out
            tree["training"] = TrainingConfig.rescheduled(training, value)
        else:
            config_tree.set_dotted(tree, "training.iterations", value)
    for key, value in overrides.items():
        if key in relative:
            value = _scaled(tree, key, value)
        config_tree.set_dotted(tree, key, value)
    return RunConfig.from_dict(tree)


def as_saved(tree: dict[str, Any]) -> dict[str, Any]:
    """A run folder's saved config ``tree`` with every setting of ``SAVED_BEFORE`` it lacks set to
    the value its run had."""
    tree = copy.deepcopy(tree)
    for (section, name), value in SAVED_BEFORE.items():
        held = [k for k in (section, *(old for old, new in RENAMED_SECTIONS.items() if new == section)) if k in tree]
        for key in held or [section]:
            tree.setdefault(key, {}).setdefault(name, value)
    return tree


def current_names(tree: dict[str, Any], source: str) -> dict[str, Any]:
    """``tree`` with every section under a former name (``RENAMED_SECTIONS``) under its name,
    one note per renamed section; InputError when a tree holds a section under both names."""
    for old, new in RENAMED_SECTIONS.items():
        if old not in tree:
            continue
        if new in tree:
            raise InputError(f"{source}: sections {old!r} and {new!r} are the same section (its former and "
                             f"current name); keep {new!r}")
        log.warning("%s: config section %r is now called %r (read as %r)", source, old, new, new)
        tree = {new if k == old else k: v for k, v in tree.items()}
    return tree


def _current_key(key: str, note: bool = False) -> str:
    """A dotted override key with a former section name replaced (``RENAMED_SECTIONS``)."""
    head, dot, rest = key.partition(".")
    if head not in RENAMED_SECTIONS:
        return key
    new = f"{RENAMED_SECTIONS[head]}{dot}{rest}"
    if note:
        log.warning("--set %s: config section %r is now called %r; read as %s", key, head, RENAMED_SECTIONS[head], new)
    return new


def _scaled(tree: dict[str, Any], key: str, factor: Any) -> Any:
    """The value ``key`` has before the override (tree, else the dataclass default) x factor."""
    base = config_tree.get_dotted(tree, key)
    if base is None:
        base = config_tree.get_dotted(RunConfig().to_dict(), key)
    if not isinstance(base, (int, float)) or isinstance(base, bool) or not isinstance(factor, (int, float)):
        raise InputError(f"override {key!r}: a relative knob needs a numeric base and factor "
                         f"(base {base!r}, factor {factor!r})")
    return type(base)(round(base * factor)) if isinstance(base, int) else base * factor


def _read_config_file(config_file: str | Path | dict[str, Any]) -> dict[str, Any]:
    if isinstance(config_file, dict):
        data = config_file
    else:
        from fixer4d.jsonfile import read_json_object

        path = Path(config_file)
        if not path.is_file():
            raise InputError(f"--config {path}: no such file")
        data = read_json_object(path, f"--config {path}", "write a JSON config such as `fixer4d run SCENE --print-config` shows")
    if not isinstance(data, dict):
        raise InputError("a config file must hold a JSON object")
    if "format_version" in data and "config" in data:  # a run folder's config.json
        data = data["config"]
    return data


def migrate_v1(data: dict[str, Any]) -> dict[str, Any]:
    """A format-1 config.json (first landing) as a format-2 config tree.

    Format 1 had two shapes: `fixer4d run` wrote {"scene", "pipeline": {..., "init": {"method",
    ...}, "eval_stride", "restoration_rows", "restorer"}}, `fixer4d reconstruct` wrote {"scene",
    "init": {"method"}, "stage1": {...}, "stage2"?}.
    """
    if "pipeline" in data:
        p = dict(data["pipeline"])
        tree: dict[str, Any] = {"scene": p.pop("scene", data.get("scene", {}))}
        ev = {}
        if "eval_stride" in p:
            ev["stride"] = p.pop("eval_stride")
        if "restoration_rows" in p:
            ev["restoration_rows"] = p.pop("restoration_rows")
        tree["eval"] = ev
        tree.update(p)
        tree["restorer"] = RestoreConfig.from_dict(tree.get("restorer")).to_dict()  # flat warp keys -> warp
        return tree
    tree = {k: data[k] for k in ("scene", "init", "stage2") if k in data}
    training = dict(data.get("stage1", {}))
    training.pop("progress", None)
    tree["training"] = training
    tree.update({"baseline_sparse": False, "stage2": {**tree.get("stage2", {})}})
    return tree
