"""graspd_lab: the lab distribution (graspd-lab): the rendered world, the pybullet simulator, training data,
training and export.  It depends on graspd; graspd's server never imports it."""

__version__ = "0.1.0"
