"""A grid rig's extra cameras between grid positions ("rig.extra") and an explicit held-out list
("rig.test"): what a validation spec needs to add cameras to a rig without moving its train ones."""
from __future__ import annotations

import numpy as np
import pytest

from fixer4d.errors import InputError
from fixer4d.scene.synthetic import SyntheticScene, build_rig, read_spec


def _grid_spec(**rig):
    spec, _ = read_spec("demo")
    spec["rig"].update(rig)
    return spec


def test_extra_cameras_follow_the_grid_and_leave_it_untouched():
    plain = build_rig(_grid_spec())
    extra = build_rig(_grid_spec(extra=[[1, 2], [0.5, 0.5]]))
    assert len(extra) == len(plain) + 2 and extra[16].name == "cam16" and extra[17].name == "cam17"
    for a, b in zip(plain, extra):
        assert np.array_equal(a.c2w, b.c2w) and np.array_equal(a.K, b.K)
    # An integer grid position reproduces that grid camera (row 1, col 2 = cam06).
    assert np.allclose(extra[16].c2w, plain[6].c2w, atol=1e-12)
    # Row 0.5, col 0.5 sits at the centre of the cell cam00, cam01, cam04, cam05, looking the same way.
    cell = np.mean([plain[i].center for i in (0, 1, 4, 5)], axis=0)
    assert np.allclose(extra[17].center, cell, atol=1e-12)
    assert np.allclose(extra[17].c2w[:3, :3], plain[0].c2w[:3, :3], atol=1e-12)


def test_extra_cameras_are_refused_where_they_have_no_meaning():
    with pytest.raises(InputError, match=r"rig.extra\[1\]"):
        build_rig(_grid_spec(extra=[[0.5, 0.5], [1.0]]))
    with pytest.raises(InputError, match="rig.extra"):
        build_rig(_grid_spec(extra=[0.5, 0.5, 0.5]))
    spec, _ = read_spec("tiny")
    spec["rig"]["extra"] = [[0.5, 0.5]]
    with pytest.raises(InputError, match="layout"):
        build_rig(spec)


def test_an_explicit_held_out_list_leaves_other_cameras_unused():
    spec = _grid_spec(extra=[[0.5, 0.5]], train=[0, 3, 12, 15], test=[16])
    scene = SyntheticScene(spec)
    assert scene.train_ids == [0, 3, 12, 15] and scene.test_ids == [16]
    for bad, match in (([3, 16], "none of the train"), ([17], "outside"), ([], "at least one"), ("all", "list")):
        with pytest.raises(InputError, match=match):
            SyntheticScene(_grid_spec(extra=[[0.5, 0.5]], train=[0, 3, 12, 15], test=bad))


def test_extra_cameras_need_an_explicit_train_list():
    """"auto" picks the train cameras from every camera: added (held-out) ones must not move them."""
    with pytest.raises(InputError, match="rig.extra needs an explicit rig.train"):
        SyntheticScene(_grid_spec(extra=[[0.5, 0.5]]))
    scene = SyntheticScene(_grid_spec(extra=[[0.5, 0.5]]), train_ids=[0, 3, 12, 15], test_ids=[16])
    assert scene.train_ids == [0, 3, 12, 15] and scene.test_ids == [16]
