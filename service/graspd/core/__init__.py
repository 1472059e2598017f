"""graspd.core: the value objects and rules every layer shares (cloud, hand geometry, grasp set, frames,
warnings, errors, limits, the camera model).  Imports nothing from graspd above it."""
