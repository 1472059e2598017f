"""graspd.gpd: Grasp Pose Detection (ten Pas et al., Algorithm 1), one module per step: preprocess, environment,
candidates, images, classifier, selection; `detector` runs them.  Imports only graspd.core."""
