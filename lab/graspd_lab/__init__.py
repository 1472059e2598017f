"""graspd_lab: the lab distribution (graspd-lab): the rendered world, the pybullet simulator, training data,
training and export.  It depends on graspd; graspd's server never imports it."""

from graspd_lab.open3d_import import defer_plotly_drawing

__version__ = "0.1.0"

defer_plotly_drawing()  # open3d's dash/plotly drawing loads when used, not with open3d (~0.4 s of start-up)
