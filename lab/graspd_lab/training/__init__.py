"""Training pipeline: objects and views from meshes, antipodal labels, datasets, CNN, evaluation."""
