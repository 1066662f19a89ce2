"""train.fields: n stage-1 fields merged into one model (training.fields)."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from fixer4d.errors import InputError
from fixer4d.model.camera_response import CameraResponse
from fixer4d.model.spacetime import ModelConfig, SpacetimeGaussians
from fixer4d.train.fields import FIELD_SEED_OFFSET, field_seed, mean_response, merge_fields


def _field(n: int, seed: int, config: ModelConfig | None = None) -> SpacetimeGaussians:
    rng = np.random.default_rng(seed)
    model = SpacetimeGaussians.from_points(rng.normal(size=(n, 3)), rng.uniform(size=(n, 3)),
                                           rng.uniform(size=n), config=config or ModelConfig())
    with torch.no_grad():
        model.opacity_logits.copy_(torch.from_numpy(rng.normal(scale=3.0, size=n)).float())
    model.set_dynamic(torch.from_numpy(rng.uniform(size=n) < 0.5))
    return model


def test_one_field_is_the_model_itself():
    a = _field(7, 0)
    merged = merge_fields([a])
    for name, value in a.tensors().items():
        torch.testing.assert_close(merged.tensors()[name], value, rtol=0, atol=0)


def test_the_union_keeps_every_row_and_divides_each_opacity_by_the_field_count():
    a, b, c = _field(5, 1), _field(8, 2), _field(3, 3)
    merged = merge_fields([a, b, c])
    assert merged.num_gaussians == 16
    want = torch.cat([torch.sigmoid(m.opacity_logits.detach().double()) for m in (a, b, c)]) / 3
    torch.testing.assert_close(torch.sigmoid(merged.opacity_logits.detach().double()), want, rtol=1e-6, atol=1e-9)
    torch.testing.assert_close(merged.means.detach(), torch.cat([a.means, b.means, c.means]).detach(), rtol=0, atol=0)
    assert torch.equal(merged.dynamic, torch.cat([a.dynamic, b.dynamic, c.dynamic]))


def test_an_opaque_gaussian_stays_finite_when_merged():
    a = _field(4, 4)
    with torch.no_grad():
        a.opacity_logits.fill_(40.0)  # sigmoid == 1.0 in float32
    merged = merge_fields([a, _field(2, 5)])
    assert torch.isfinite(merged.opacity_logits).all()
    torch.testing.assert_close(torch.sigmoid(merged.opacity_logits[:4].double()),
                               torch.full((4,), 0.5, dtype=torch.float64), rtol=1e-6, atol=1e-6)


def test_fields_with_other_terms_are_refused():
    with pytest.raises(InputError, match="model terms"):
        merge_fields([_field(3, 0), _field(3, 1, ModelConfig(motion_degree=1))])
    with pytest.raises(InputError, match="no fields"):
        merge_fields([])


def test_field_seeds():
    assert field_seed(7, 0) == 7
    assert field_seed(7, 2) == 7 + 2 * FIELD_SEED_OFFSET


def test_the_merged_response_is_the_fields_mean():
    r1, r2 = CameraResponse(4), CameraResponse(4)
    with torch.no_grad():
        r1.log_gain.normal_(), r1.bias.normal_(), r2.log_gain.normal_(), r2.bias.normal_()
    mean = mean_response([r1, r2])
    torch.testing.assert_close(mean.log_gain, (r1.log_gain + r2.log_gain).detach() / 2)
    torch.testing.assert_close(mean.bias, (r1.bias + r2.bias).detach() / 2)
    assert mean_response([None, None]) is None
    with pytest.raises(InputError):
        mean_response([r1, None])


def test_frozen_rows_are_kept_once_at_their_own_opacity():
    """A later segment's shared static rows are in every field; the merged model has them once."""
    shared = _field(3, 9)
    fields = []
    for seed in (10, 11):
        field = _field(4, seed)
        field.append({k: v for k, v in shared.tensors().items() if k not in ("dynamic", "frozen")})
        field.set_frozen(torch.arange(field.num_gaussians) >= 4)
        fields.append(field)
    merged = merge_fields(fields)
    assert merged.num_gaussians == 4 + 4 + 3 and merged.num_frozen == 3
    torch.testing.assert_close(merged.opacity_logits[merged.frozen], shared.opacity_logits.detach(), rtol=0, atol=0)
    own = torch.cat([torch.sigmoid(f.opacity_logits[:4].detach().double()) for f in fields]) / 2
    torch.testing.assert_close(torch.sigmoid(merged.opacity_logits[~merged.frozen].double()), own,
                               rtol=1e-6, atol=1e-9)


def test_extreme_opacity_logits_stay_finite_and_exact_when_merged():
    a = _field(3, 12)
    with torch.no_grad():
        a.opacity_logits.copy_(torch.tensor([-1000.0, 0.0, 30.0]))
    merged = merge_fields([a, _field(1, 13)]).opacity_logits.detach().double()[:3]
    assert torch.isfinite(merged).all()
    assert float(merged[0]) == pytest.approx(-1000.0 - np.log(2.0), abs=1e-3)  # sigmoid(o) / 2 ~ e^o / 2
    assert float(torch.sigmoid(merged[1])) == pytest.approx(0.25, abs=1e-7)
