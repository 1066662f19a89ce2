"""PhysGaussian's anisotropy term (``training.scale_ratio_weight``): zero within the bound, a pull on
the long axes of needles only, and through a training step to the model's log-scales."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from fixer4d.errors import InputError
from fixer4d.train.config import TrainingConfig
from fixer4d.train.model_init import model_from_clouds
from fixer4d.train.scale_ratio import scale_ratio_penalty
from fixer4d.train.trainer import Trainer


def test_zero_within_the_bound_and_the_excess_beyond_it():
    ls = torch.log(torch.tensor([[1.0, 1.0, 1.0], [1.0, 2.0, 9.0], [0.1, 1.0, 3.0]], dtype=torch.float64))
    assert float(scale_ratio_penalty(ls[:2], 10.0)) == 0.0
    assert float(scale_ratio_penalty(ls, 10.0)) == pytest.approx((30.0 - 10.0) / 3)
    assert float(scale_ratio_penalty(ls[:0], 10.0)) == 0.0


def test_the_gradient_shortens_the_long_axis_and_widens_the_short_one_of_needles_only():
    ls = torch.log(torch.tensor([[1.0, 2.0, 3.0], [0.1, 1.0, 5.0]], dtype=torch.float64)).requires_grad_()
    scale_ratio_penalty(ls, 10.0).backward()
    g = ls.grad
    assert torch.all(g[0] == 0)  # 3 : 1 is within the bound
    assert g[1, 2] > 0 and g[1, 0] < 0 and g[1, 1] == 0  # descent pulls s_max in and s_min out
    assert float(g[1, 2]) == pytest.approx(50.0 / 2)  # d/d log s_max of mean(s_max / s_min - r) = ratio / N


def test_against_the_middle_axis_only_needles_pay():
    disc, needle = [0.1, 3.0, 3.0], [0.1, 0.1, 3.0]  # 30 : 30 : 1 and 30 : 1 : 1
    ls = torch.log(torch.tensor([disc, needle], dtype=torch.float64))
    assert float(scale_ratio_penalty(ls, 10.0, "shortest")) == pytest.approx(20.0)
    assert float(scale_ratio_penalty(ls, 10.0, "middle")) == pytest.approx(10.0)
    assert float(scale_ratio_penalty(ls[:1], 10.0, "middle")) == 0.0


def test_bad_settings_are_refused():
    with pytest.raises(InputError, match="scale_ratio_weight"):
        TrainingConfig(scale_ratio_weight=-1.0)
    with pytest.raises(InputError, match="scale_ratio_max"):
        TrainingConfig(scale_ratio_max=0.5)
    with pytest.raises(InputError, match="scale_ratio_against 'longest'"):
        TrainingConfig(scale_ratio_against="longest")


def test_a_training_step_with_the_term_reaches_the_log_scales(small_scene, small_clouds, make_config):
    def first_step_grad(weight: float) -> torch.Tensor:
        cfg = make_config(2, init_max_points=200, scale_ratio_weight=weight, scale_ratio_max=2.0)
        model = model_from_clouds(small_clouds, small_scene, cfg)
        with torch.no_grad():  # make Gaussian 0 a needle: 8 : 1
            model.log_scales[0] = torch.log(torch.tensor([0.01, 0.02, 0.08], dtype=model.log_scales.dtype))
        trainer = Trainer(model, small_scene, cfg)
        grads = {}
        model.log_scales.register_hook(lambda g: grads.setdefault("g", g.detach().clone()))
        trainer.step()
        return grads["g"]

    plain, pulled = first_step_grad(0.0), first_step_grad(1.0)
    assert math.isfinite(float(pulled.abs().sum()))
    # the same draws and renders: the term adds V x weight x d(penalty)/d(log s) to the needle's
    # axes (the step takes the gradient of V x L, V views per step), nothing to the others
    extra = (pulled - plain).double().numpy()
    n, views = plain.shape[0], min(make_config(2).views_per_step, len(small_scene.train_ids))
    np.testing.assert_allclose(extra[0], [-8.0 * views / n, 0.0, 8.0 * views / n], rtol=1e-3)
    np.testing.assert_allclose(extra[1:], 0.0, atol=1e-7)


def test_off_it_keys_a_training_as_before_the_option_existed():
    from fixer4d.train.checkpoints import result_settings

    off = result_settings(TrainingConfig().to_dict())
    assert not any(k.startswith("scale_ratio") for k in off)  # earlier run folders resume as they were
    on = result_settings(TrainingConfig(scale_ratio_weight=0.01).to_dict())
    assert (on["scale_ratio_weight"], on["scale_ratio_max"], on["scale_ratio_against"]) == (0.01, 10.0, "shortest")
