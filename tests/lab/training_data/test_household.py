"""Household models in the catalogue: every one at its true size, its mass from its URDF, its centre of mass and
inertia from its collision mesh (written into the vendored URDF), and the held-out ones refused for training."""

from __future__ import annotations

import itertools
import re

import numpy as np
import pytest

from graspd_lab.world import household
from graspd_lab.world.held_out import HeldOutObjectError
from graspd_lab.world.objects import check_not_held_out, household_object, load_object, object_catalogue


def _file_extent(name: str) -> np.ndarray:
    """Extents (m) of every vertex in the model's collision OBJ, read as plain text."""
    text = (household.HOUSEHOLD_DIR / f"{name}_collision.obj").read_text()
    v = np.array([ln.split()[1:4] for ln in text.splitlines() if ln.startswith("v ")], np.float64)
    return np.ptp(v, axis=0)


def test_every_household_model_loads_at_its_true_size() -> None:
    names = household.household_names()
    assert len(names) == 295
    specs = object_catalogue(num_urdfs=0, household_models=True)
    assert len(specs) == 295 - len(household.HELD_OUT)
    for kind, index in specs:
        obj = load_object(kind, index)
        assert obj.scale == 1.0
        np.testing.assert_allclose(obj.extent, _file_extent(names[index]), atol=1e-6)
    held = household_object(names.index(household.HELD_OUT[0]), held_out_ok=True)
    np.testing.assert_allclose(held.extent, _file_extent(household.HELD_OUT[0]), atol=1e-6)


def test_vendored_urdfs_carry_the_mass_properties_of_their_collision_mesh() -> None:
    for name in household.household_names():
        urdf = (household.HOUSEHOLD_DIR / f"{name}.urdf").read_text()
        props = household.household_mass_properties(name)
        assert props.mass == pytest.approx(household.urdf_mass(urdf))
        xyz = [float(x) for x in re.search(r'<origin xyz="([^"]+)"', urdf).group(1).split()]  # type: ignore[union-attr]
        np.testing.assert_allclose(xyz, props.com, atol=1e-8)
        diag = [float(re.search(rf'{k}="([^"]+)"', urdf).group(1)) for k in ("ixx", "iyy", "izz")]  # type: ignore[union-attr]
        np.testing.assert_allclose(diag, props.principal_moments, rtol=1e-6)
        assert 'ixx="1"' not in urdf  # the source's placeholder is gone
        assert np.all(props.principal_moments > 0)


def test_mass_properties_of_a_box_split_in_two_parts_are_the_box_s() -> None:
    a, b, c = 0.04, 0.10, 0.16
    halves = [np.array(list(itertools.product(xs, [0, b], [0, c]))) + [0.2, -0.1, 0.05]
              for xs in ([0, a / 2], [a / 2, a])]
    props = household.mass_properties(halves, mass=0.5)
    assert props.volume == pytest.approx(a * b * c)
    np.testing.assert_allclose(props.com, [0.2 + a / 2, -0.1 + b / 2, 0.05 + c / 2], atol=1e-12)
    np.testing.assert_allclose(props.inertia, np.diag([b * b + c * c, a * a + c * c, a * a + b * b]) * 0.5 / 12,
                               atol=1e-12)


def test_a_box_shaped_model_has_the_analytic_box_inertia() -> None:
    name = "box_poisson_006"  # its collision hull fills 99% of its principal-axis bounding box
    props = household.household_mass_properties(name)
    v = np.vstack(household.read_obj_parts(household.HOUSEHOLD_DIR / f"{name}_collision.obj"))
    e = np.ptp((v - props.com) @ props.principal_axes, axis=0)
    box = props.mass / 12 * np.array([e[1] ** 2 + e[2] ** 2, e[0] ** 2 + e[2] ** 2, e[0] ** 2 + e[1] ** 2])
    np.testing.assert_allclose(props.principal_moments, box, rtol=0.05)
    np.testing.assert_allclose(props.com, (v.min(axis=0) + v.max(axis=0)) / 2, atol=0.002)


def test_loading_a_held_out_household_model_for_training_raises() -> None:
    name = household.HELD_OUT[0]
    index = household.household_names().index(name)
    with pytest.raises(HeldOutObjectError):
        load_object("household", index)
    with pytest.raises(HeldOutObjectError):
        check_not_held_out(household.household_id(name))
    with pytest.raises(HeldOutObjectError):
        household.household_urdf(name)
    listed = {household.household_names()[i] for _, i in object_catalogue(0, household_models=True)}
    assert not listed & set(household.HELD_OUT)
    check_not_held_out(household.household_id(name), held_out_ok=True)  # the held-out evaluation may


def test_the_held_out_list_is_a_seeded_fifth_of_each_family() -> None:
    assert household.HELD_OUT == household.draw_held_out(household.household_names())
    assert len(household.HELD_OUT) == 59
    for family in ("hashed", "kit", "poisson", "named"):
        members = [n for n in household.household_names() if household.name_family(n) == family]
        held = [n for n in household.HELD_OUT if household.name_family(n) == family]
        assert len(held) == round(0.2 * len(members))


def test_the_flat_training_set_is_the_thin_training_models_and_none_held_out() -> None:
    flat = household.flat_training_names()
    assert 10 <= len(flat) < len(household.training_names()) and not set(flat) & set(household.HELD_OUT)
    for name in household.training_names():
        thinnest = float(np.min(household.collision_mesh(name).get_axis_aligned_bounding_box().get_extent()))
        assert (name in flat) == (thinnest < household.FLAT_THICKNESS), name
    assert "SoftCheese_800_tex" in flat and "CokePlasticSmall_800_tex" not in flat
