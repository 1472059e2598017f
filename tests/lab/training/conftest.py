"""The tiny real model (and its dataset) shared by the training tests: made once per session (~15 s)."""

from pathlib import Path

import pytest

from graspd_lab.training.plans import train_tiny_model


@pytest.fixture(scope="session")
def tiny_model(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """models/tiny15.onnx of train_tiny_model; its dataset is at .parent.parent / "dataset"."""
    return train_tiny_model(tmp_path_factory.mktemp("tiny"), seed=0)
