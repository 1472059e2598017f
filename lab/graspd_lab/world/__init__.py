"""The one model of the world the project renders and simulates: objects (the catalogue and the
held-out rule), meshes, cameras, depth noise, the raycast renderer and scenes.  Training data, the
demo, the template tests and the pybullet benchmark (graspd_lab.sim) all build on it; nothing here
imports graspd_lab.training or graspd_lab.sim."""
