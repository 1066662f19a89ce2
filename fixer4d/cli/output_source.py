"""What the output verbs (`fixer4d render`, `fixer4d export --format ...`) need from their
MODEL_OR_RUN argument: the model, and, for a run folder, its config and scene (cameras, frame
count, fps, background). Read only: nothing is written into the run."""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from fixer4d.errors import InputError
from fixer4d.geometry.camera import Camera

# Side of the square start camera made up for a bare model file (no rig to borrow one from).
FRAMING_SIZE = 640
# Its vertical field of view; the camera backs off until the model's central 90% fits in it.
FRAMING_FOV_DEG = 50.0


@dataclass
class OutputSource:
    """A model file, or a run folder's latest model plus the run's config."""

    model_path: Path
    run: Path | None = None
    config: object | None = None  # RunConfig when ``run`` has a config.json
    _scene: object | None = field(default=None, repr=False)
    _model: object | None = field(default=None, repr=False)

    @property
    def model(self):
        if self._model is None:
            from fixer4d.model.io import load_model

            self._model = load_model(self.model_path).eval()
        return self._model

    @property
    def scene(self):
        """The run's scene; InputError naming the flag when the source is a bare model file."""
        if self.config is None:
            raise InputError(f"{self.model_path}: a bare model file has no cameras or frames; pass a run folder "
                             "(runs/<name>) for the rig's cameras, or a --camera-path")
        if self._scene is None:
            from fixer4d.pipeline.run_folder import load_scene_for

            self._scene = load_scene_for(self.config)
        return self._scene

    @property
    def background(self) -> tuple[float, float, float] | None:
        """The run's render background (``training.background`` resolved on the run's train
        views); None for a bare model file (black)."""
        if self.config is None:
            return None
        from fixer4d.train.background import resolve_background

        return resolve_background(self.config.training.background, self.scene)


def open_source(source: str | Path, model_path: Path) -> OutputSource:
    """``source`` (a model file or a run folder) with ``model_path``, the model the verb resolved
    for it (``fixer4d.cli.export.resolve_model_path``: a run's latest model)."""
    from fixer4d.pipeline.run_folder import CONFIG_NAME, read_run_config

    path = Path(source)
    if path.is_dir():
        config = read_run_config(path) if (path / CONFIG_NAME).is_file() else None
        return OutputSource(model_path, run=path, config=config)
    if not model_path.is_file():
        raise InputError(f"{model_path}: no such model file or run folder")
    return OutputSource(model_path)


def clip_times(frames: int) -> list[float]:
    """The clip times of ``frames`` evenly spaced frames, t_k = k / frames (the scenes' t = f / T)."""
    if frames < 1:
        raise InputError(f"--frames must be >= 1, got {frames}")
    return [k / frames for k in range(frames)]


def framing_camera(model, width: int = FRAMING_SIZE, height: int = FRAMING_SIZE) -> Camera:
    """A camera on the model's -z side looking at its centre (image up = world -y, the OpenCV
    convention most captures use), far enough back that the central 90% of the means fits."""
    means = model.means.detach().cpu().numpy().astype(np.float64)
    if means.shape[0] == 0:
        raise InputError("the model has no Gaussians to look at")
    lo, hi = np.percentile(means, 5, axis=0), np.percentile(means, 95, axis=0)
    center = (lo + hi) / 2
    radius = max(float(np.linalg.norm(hi - lo)) / 2, 1e-3)
    distance = radius / np.tan(np.radians(FRAMING_FOV_DEG) / 2) + radius
    return Camera.look_at(center - np.array([0.0, 0.0, distance]), center, up=(0.0, -1.0, 0.0),
                          fov_y=np.radians(FRAMING_FOV_DEG), width=width, height=height, name="framing")
