"""Shim: training/train.py was split (issue 12) into config (TrainConfig), rows, augment, loop (the training
loop) and plans; kept for importers not yet updated (tests/server/conftest.py: train_tiny_model,
bench/classifier.py: load_rows).  Import from those modules instead."""

from .augment import augment, mirror_images
from .config import TrainConfig, config_command
from .loop import grasp_probability, load_checkpoint, predict_logits, recalibrate_batchnorm, train
from .plans import TINY_DATASET, export_trained, prefix_dataset, train_and_export, train_plan, train_tiny_model
from .rows import feedback_rows, load_rows, row_cache, training_rows

__all__ = ["TINY_DATASET", "TrainConfig", "augment", "config_command", "export_trained", "feedback_rows",
           "grasp_probability", "load_checkpoint", "load_rows", "mirror_images", "predict_logits", "prefix_dataset",
           "recalibrate_batchnorm", "row_cache", "train", "train_and_export", "train_plan", "train_tiny_model",
           "training_rows"]
