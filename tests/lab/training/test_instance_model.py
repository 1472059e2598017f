"""Instance models (IROS 2016 GPD, Figure 7): a mesh file is checked, made into a one-object dataset with the
dataset machinery, a base model is fine-tuned on it (its weights read back from the shipped ONNX when there is
no .pt), and generic, category and instance models are compared on the object's held-out views in the card."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import open3d as o3d
import pytest
import torch
from torch import nn

from fixtures import write_mesh
from graspd.cli.main import main as graspd_main
from graspd.gpd.classifier import OnnxGraspClassifier, default_models_dir, read_card
from graspd.io.mesh_file import MeshError
from graspd.store.instances import PROGRESS_PREFIX, InstanceError
from graspd_lab.training.dataset import read_manifest, read_split
from graspd_lab.training.instance import InstanceParams, make_instance_dataset, network_from_onnx, train_instance
from graspd_lab.training.instance_cli import main as instance_main
from graspd_lab.training.rows import load_rows
from graspd_lab.world.mesh_file import read_mesh_object
from graspd_lab.world.meshes import box_mesh, cylinder_mesh

SHIPPED = default_models_dir()
TINY = InstanceParams(views=4, per_view=32, epochs=1, max_minutes=0.2, batch_size=32, threads=1)


@pytest.fixture
def box_ply(tmp_path: Path) -> Path:
    return write_mesh(tmp_path / "box.ply", box_mesh(0.05, 0.08, 0.15))


@pytest.fixture
def base_models(tmp_path: Path) -> Path:
    """A models folder with the shipped generic and category models (their ONNX and cards only)."""
    folder = tmp_path / "models"
    folder.mkdir()
    for name in ("generic15", "box15", "cylinder15"):
        if not (SHIPPED / f"{name}.onnx").is_file():
            pytest.fail(f"the shipped model {name} is expected in {SHIPPED}")
        for suffix in (".onnx", ".json"):
            shutil.copy(SHIPPED / f"{name}{suffix}", folder / f"{name}{suffix}")
    return folder


# ---- the mesh file ----


def test_a_mesh_in_metres_is_read_centred_with_its_size(tmp_path: Path) -> None:
    mesh = box_mesh(0.05, 0.08, 0.15)
    mesh.translate([0.3, -0.2, 1.0])
    obj = read_mesh_object(write_mesh(tmp_path / "off.stl", mesh), "box", "box")
    assert np.allclose(sorted(obj.extent), [0.05, 0.08, 0.15], atol=1e-6)
    assert np.allclose(obj.mesh.get_axis_aligned_bounding_box().get_center(), 0.0, atol=1e-9)
    assert obj.category == "box" and obj.source.startswith("file:off.stl:sha256=")


@pytest.mark.parametrize(("name", "content", "words"), [
    ("mm.obj", "millimetres", "metres"),
    ("km.ply", "kilometres", "below 0.01 m"),
    ("wide.ply", "wide", "aperture"),
    ("cloud.ply", "points", "no triangles"),
    ("empty.obj", b"", "empty"),
    ("junk.stl", b"not a mesh at all", "no triangles|declaring 0 triangles"),
    ("nan.obj", b"v 0 0 0\nv 0.05 0 0\nv 0 nan 0\nf 1 2 3\n", "non-finite"),
    ("bad_index.obj", b"v 0 0 0\nv 0.05 0 0\nv 0 0.05 0\nf 1 2 9\n", "no triangles|index"),
    ("box.step", b"ISO-10303-21;", ".obj, .stl, .ply"),
])
def test_bad_meshes_are_refused_naming_the_field(tmp_path: Path, name: str, content: str | bytes,
                                                 words: str) -> None:
    path = tmp_path / name
    if content == "millimetres":
        write_mesh(path, box_mesh(50.0, 80.0, 150.0))
    elif content == "kilometres":
        write_mesh(path, box_mesh(5e-5, 8e-5, 1.5e-4))
    elif content == "wide":
        write_mesh(path, box_mesh(0.3, 0.3, 0.3))
    elif content == "points":
        cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.random.default_rng(0).random((50, 3)) * 0.1))
        assert o3d.io.write_point_cloud(str(path), cloud)
    else:
        assert isinstance(content, bytes)
        path.write_bytes(content)
    with pytest.raises(MeshError) as err:
        read_mesh_object(path, "x", field="mesh")
    assert err.value.field == "mesh"
    assert any(w in err.value.message for w in words.split("|")), err.value.message


def test_a_cylinder_wider_than_the_hand_one_way_but_not_the_other_is_accepted(tmp_path: Path) -> None:
    """A can 8 cm across and 30 cm tall: too tall to close on lengthwise, fine across."""
    obj = read_mesh_object(write_mesh(tmp_path / "can.ply", cylinder_mesh(0.04, 0.3)), "can", "cylinder")
    assert max(obj.extent) == pytest.approx(0.3, abs=1e-6)


# ---- the dataset and the base weights ----


def test_the_instance_dataset_has_the_dataset_format_and_a_view_split(tmp_path: Path, box_ply: Path) -> None:
    obj = read_mesh_object(box_ply, "box", "box")
    manifest = make_instance_dataset(obj, tmp_path / "data", InstanceParams(views=6, per_view=32))
    assert read_manifest(tmp_path / "data")["dataset_sha256"] == manifest["dataset_sha256"]
    assert [o["name"] for o in manifest["objects"]] == ["box"] and len(manifest["views"]) == 6
    split = read_split(tmp_path / "data", "view")
    parts = {p: {tuple(v) for v in split[p]} for p in ("train", "val", "test")}
    assert sum(len(p) for p in parts.values()) == 6 and not (parts["train"] & parts["test"])
    assert not (parts["val"] & parts["test"]) and not (parts["train"] & parts["val"])
    for part in ("train", "val", "test"):
        images, labels, cats = load_rows(tmp_path / "data", "view", part, "15")
        assert images.shape[1:] == (15, 60, 60) and 0 < labels.mean() < 1, part
        assert set(cats.tolist()) == {0}  # box
    assert manifest["counts"]["positive"] * 2 == manifest["counts"]["total"]


def test_the_base_network_read_back_from_onnx_scores_as_the_onnx_model(tmp_path: Path, box_ply: Path) -> None:
    """Batch norm is folded into the convolutions in the ONNX graph; the rebuilt network restores it from the
    images' statistics: equal in eval mode, and close in training mode (batch statistics), where an identity
    batch norm would renormalise every channel and change the scores."""
    make_instance_dataset(read_mesh_object(box_ply, "box"), tmp_path / "data", InstanceParams(views=4, per_view=64))
    images, _, _ = load_rows(tmp_path / "data", "view", "train", "15")
    card = read_card(SHIPPED / "generic15.json")
    net = network_from_onnx(SHIPPED / "generic15.onnx", card, images)
    x = torch.from_numpy(images.astype(np.float32) / 255.0)
    onnx_scores = OnnxGraspClassifier(SHIPPED / "generic15.onnx", card, threads=1).score(images)
    with torch.no_grad():
        eval_scores = torch.softmax(net.eval()(x), 1)[:, 1].numpy()
        net.train()
        for m in net.modules():
            if isinstance(m, nn.Dropout):
                m.eval()
        train_scores = torch.softmax(net(x), 1)[:, 1].numpy()
    assert np.max(np.abs(eval_scores - onnx_scores)) < 1e-4
    assert np.mean(np.abs(train_scores - onnx_scores)) < 0.02


# ---- the whole pipeline ----


def test_an_instance_model_is_made_and_compared_on_held_out_views(tmp_path: Path, box_ply: Path,
                                                                  base_models: Path) -> None:
    events: list[dict[str, object]] = []
    path = train_instance(box_ply, "box_i", base_models, "box", TINY, log=lambda line: None,
                          progress=events.append)
    assert path == base_models / "box_i.onnx"
    card = read_card(path.with_suffix(".json"))
    assert card["instance"]["base_model"] == "box15" and card["instance"]["category"] == "box"
    assert card["training"]["config"]["init_from"].endswith("box15-from-onnx.pt")
    compared = card["instance_comparison"]["models"]
    assert {k: v["role"] for k, v in compared.items()} == {
        "generic15": "generic", "box15": "category", "cylinder15": "other_category", "box_i": "instance"}
    n = {m["n"] for m in compared.values()}
    assert len(n) == 1 and n.pop() == card["metrics"]["view_test"]["n"] > 0
    for m in compared.values():
        assert 0.0 <= m["ra99p"] <= 1.0 and 0.5 <= m["average_precision"] <= 1.0 and m["fits_hand"] is True
    assert compared["box_i"]["accuracy"] == pytest.approx(card["metrics"]["view_test"]["accuracy"])
    stages = [e["stage"] for e in events]
    assert stages[0] == "dataset" and "training" in stages and stages[-1] == "done"
    assert max(e.get("view", 0) for e in events) == TINY.views  # type: ignore[type-var]
    # the name is now taken, and the new model loads like any other
    with pytest.raises(InstanceError) as err:
        train_instance(box_ply, "box_i", base_models, None, TINY, log=lambda line: None)
    assert err.value.field == "name"
    scores = OnnxGraspClassifier(path).score(np.zeros((2, 15, 60, 60), np.uint8))
    assert scores.shape == (2,)


def test_the_command_line_refuses_bad_options_by_field(tmp_path: Path, box_ply: Path, base_models: Path,
                                                       capsys: pytest.CaptureFixture[str]) -> None:
    mm = write_mesh(tmp_path / "mm.obj", box_mesh(50.0, 80.0, 150.0))
    assert instance_main(["--instance", str(mm), "--name", "mm", "--models-dir", str(base_models),
                          "--progress-json"]) == 2
    out = capsys.readouterr()
    event = json.loads(out.out.strip().splitlines()[-1].removeprefix(PROGRESS_PREFIX))
    assert event["stage"] == "failed" and event["field"] == "mesh" and "metres" in event["error"]
    assert instance_main(["--instance", str(box_ply), "--name", "../evil", "--models-dir", str(base_models)]) == 2
    assert "name:" in capsys.readouterr().err
    assert instance_main(["--instance", str(box_ply), "--name", "ok", "--views", "2",
                          "--models-dir", str(base_models)]) == 2
    assert "views:" in capsys.readouterr().err
    assert not (base_models / "mm.onnx").exists() and not (base_models / "ok.onnx").exists()


def test_graspd_train_instance_makes_the_model_and_prints_the_comparison(
        box_ply: Path, base_models: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert graspd_main(["train", "--instance", str(box_ply), "--name", "box_cli", "--category", "box",
                        "--views", "3", "--per-view", "16", "--epochs", "1", "--max-minutes", "0.1", "--threads", "1",
                        "--models-dir", str(base_models)]) == 0
    out = capsys.readouterr().out
    assert "box15 (category): accuracy" in out and "box_cli (instance): accuracy" in out
    card = read_card(base_models / "box_cli.json")
    assert card["instance"]["params"]["views"] == 3 and card["instance"]["base_model"] == "box15"
    assert card["training"]["config"]["max_minutes"] == 0.1


@pytest.mark.slow
def test_the_instance_model_beats_the_category_model_on_its_object(tmp_path: Path, box_ply: Path,
                                                                   base_models: Path) -> None:
    """Figure 7's claim with the default budget (24 views, 2 minutes): fine-tuned on the box's training views,
    the model classifies the box's held-out views better than the category model it started from."""
    path = train_instance(box_ply, "box_i", base_models, "box", InstanceParams(max_minutes=2.0),
                          log=lambda line: None)
    compared = read_card(path.with_suffix(".json"))["instance_comparison"]["models"]
    assert compared["box_i"]["accuracy"] > compared["box15"]["accuracy"]
    assert compared["box_i"]["average_precision"] > compared["box15"]["average_precision"]
