"""Object sources: held-out pybullet objects are refused; every object fits the hand and has a category."""

from __future__ import annotations

import numpy as np
import pytest

from graspd.core.hand import HandGeometry
from graspd_lab.world.objects import (
    PROCEDURAL_KINDS,
    HeldOutObjectError,
    load_object,
    object_catalogue,
    procedural_object,
    random_urdf_mesh,
)


@pytest.mark.parametrize("index", [900, 950, 999])
def test_held_out_urdfs_are_refused(index: int) -> None:
    with pytest.raises(HeldOutObjectError, match="held-out"):
        random_urdf_mesh(index)
    with pytest.raises(HeldOutObjectError):
        load_object("urdf", index)


def test_held_out_urdf_loads_only_when_asked_for_the_held_out_evaluation() -> None:
    pytest.importorskip("pybullet")  # pybullet_data holds the random_urdfs (the lab, graspd-lab)
    obj = random_urdf_mesh(900, held_out_ok=True)
    assert len(obj.mesh.triangles) > 0


def test_catalogue_never_lists_held_out_objects() -> None:
    specs = object_catalogue(900, {"box": 2})
    urdfs = [i for kind, i in specs if kind == "urdf"]
    assert urdfs == list(range(900))
    with pytest.raises(ValueError, match="held out"):
        object_catalogue(901)


def test_urdf_mesh_uses_the_urdf_scale_and_fits_the_hand() -> None:
    pytest.importorskip("pybullet")  # pybullet_data holds the random_urdfs (the lab, graspd-lab)
    hand = HandGeometry()
    obj = random_urdf_mesh(0, hand)
    assert obj.category == "other" and obj.source.endswith("random_urdfs/000/000.urdf")
    assert obj.scale == pytest.approx(0.015)  # 000.urdf: scale 0.015, already graspable
    v = np.asarray(obj.mesh.vertices)
    assert np.allclose((v.max(axis=0) + v.min(axis=0)) / 2, 0.0, atol=1e-9)
    assert min(obj.extent) <= hand.max_aperture


@pytest.mark.parametrize("kind", PROCEDURAL_KINDS)
def test_procedural_objects_are_graspable_closed_and_categorised(kind: str) -> None:
    hand = HandGeometry()
    for i in range(4):
        obj = procedural_object(kind, i, seed=3, hand=hand)
        v = np.asarray(obj.mesh.vertices)
        _, _, axes = np.linalg.svd(v - v.mean(axis=0), full_matrices=False)
        local = v @ axes.T
        assert (local.max(axis=0) - local.min(axis=0)).min() <= 0.8 * hand.max_aperture + 1e-9
        assert obj.category == (kind if kind in ("box", "cylinder") else "other")
        if kind != "composite":
            assert obj.mesh.is_watertight()
        again = procedural_object(kind, i, seed=3, hand=hand)
        assert np.array_equal(np.asarray(again.mesh.vertices), v)
