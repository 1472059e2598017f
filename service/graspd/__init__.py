"""graspd: Grasp Pose Detection (ten Pas, Gualtieri, Saenko, Platt) as a library and a microservice."""

__version__ = "0.1.0"
