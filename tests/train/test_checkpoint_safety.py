"""Checkpoints load without unpickling code: weights_only=True, versioned, clear errors."""
from __future__ import annotations

import pickle
from pathlib import Path

import pytest
import torch

from fixer4d.errors import InputError
from fixer4d.train.checkpoints import CHECKPOINT_FORMAT, read_checkpoint
from fixer4d.train.model_init import model_from_clouds
from fixer4d.train.trainer import Trainer


class _Payload:
    """Pickles to a call of ``open(marker, "w")``: unpickling it creates the marker file."""

    def __init__(self, marker: Path) -> None:
        self.marker = str(marker)

    def __reduce__(self):
        return (open, (self.marker, "w"))


def _malicious_checkpoint(path: Path, marker: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    torch.save({"format": CHECKPOINT_FORMAT, "stage": 1, "step": 6, "model": _Payload(marker)}, path)
    return path


def _trainer(small_scene, small_clouds, make_config, run_dir: Path) -> Trainer:
    cfg = make_config(12, checkpoint_every=6, init_max_points=300)
    return Trainer(model_from_clouds(small_clouds, small_scene, cfg), small_scene, cfg, run_dir=run_dir)


def test_the_payload_is_live_when_unpickled(tmp_path):
    # positive control: an ordinary unpickler runs the payload, so the refusal below is what stops it
    marker = tmp_path / "ran"
    pickle.loads(pickle.dumps(_Payload(marker))).close()
    assert marker.exists()


def test_run_folder_with_malicious_checkpoint_is_refused(small_scene, small_clouds, make_config, tmp_path):
    run = tmp_path / "run"
    marker = tmp_path / "pwned"
    _malicious_checkpoint(run / "checkpoints" / "stage1_0000006.pt", marker)
    trainer = _trainer(small_scene, small_clouds, make_config, run)
    with pytest.raises(InputError, match=r"stage1_0000006\.pt: refused to load: the checkpoint contains pickled code"):
        trainer.resume()
    assert not marker.exists()
    assert trainer.step_count == 0


def test_saved_checkpoint_round_trips_with_weights_only(small_scene, small_clouds, make_config, tmp_path):
    trainer = _trainer(small_scene, small_clouds, make_config, tmp_path)
    trainer.train(6)
    path = Trainer.list_checkpoints(tmp_path, 1)[-1]
    state = torch.load(path, map_location="cpu", weights_only=True)  # raises if anything is not plain
    assert state["format"] == CHECKPOINT_FORMAT and state["step"] == 6
    again = _trainer(small_scene, small_clouds, make_config, tmp_path)
    assert again.resume() and again.step_count == 6
    for (name, a), (_, b) in zip(trainer.model.named_parameters(), again.model.named_parameters()):
        assert torch.equal(a, b), name


@pytest.mark.parametrize("content, message", [
    (b"not a zip and not a pickle", "unreadable checkpoint"),
    (None, "not a fixer4d checkpoint"),
])
def test_foreign_or_truncated_checkpoint_names_file_and_fix(tmp_path, content, message):
    path = tmp_path / "stage1_0000001.pt"
    if content is None:
        torch.save([1, 2, 3], path)
    else:
        path.write_bytes(content)
    with pytest.raises(InputError, match=message) as info:
        read_checkpoint(path)
    assert str(path) in str(info.value) and "delete it" in str(info.value)


def test_other_checkpoint_format_gets_one_clear_sentence(small_scene, small_clouds, make_config, tmp_path):
    trainer = _trainer(small_scene, small_clouds, make_config, tmp_path)
    state = trainer.state_dict()
    state["format"] = CHECKPOINT_FORMAT + 1
    with pytest.raises(InputError, match=rf"checkpoint format {CHECKPOINT_FORMAT + 1}, but this fixer4d reads "
                                         rf"format {CHECKPOINT_FORMAT}"):
        trainer.load_state_dict(state, source="x.pt")


def test_resume_removes_checkpoint_temporaries_of_a_killed_save(small_scene, small_clouds, make_config, tmp_path):
    trainer = _trainer(small_scene, small_clouds, make_config, tmp_path)
    trainer.train(6)
    ckpts = tmp_path / "checkpoints"
    partial = ckpts / ".stage1_0000012.pt.k3j4h5.pt"  # what SIGKILL inside torch.save leaves
    partial.write_bytes(b"PK\x03\x04 half a zip")
    other_stage = ckpts / ".stage2_0000003.pt.aaaa.pt"  # another stage's: not this trainer's to touch
    other_stage.write_bytes(b"")
    again = _trainer(small_scene, small_clouds, make_config, tmp_path)
    assert again.resume() and again.step_count == 6
    assert not partial.exists() and other_stage.exists()
    assert [p.name for p in Trainer.list_checkpoints(tmp_path, 1)] == ["stage1_0000006.pt"]
