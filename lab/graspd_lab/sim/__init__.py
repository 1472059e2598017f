"""Physics-simulated dense-clutter benchmark (pybullet, DIRECT mode): the IJRR robot experiments without a robot.

- objects: the held-out test objects (pybullet_data random_urdfs 900-999), scaled to the hand;
- world: "pour" (10 objects poured into a tray, IJRR Table 1), VGN "pile" and "packed" scenes, by seed;
- sensing: CPU-rendered depth cameras with a Kinect-class noise model; passive (two fixed cameras 53 degrees
  apart), active (views along an arc) and a single side view; ViewpointClouds with camera_source;
- gripper: a free-floating parallel-jaw hand built to a HandGeometry; pre-grasp, approach, close, lift, hold;
- detectors: the SimDetector interface, a top-down geometric baseline, GPD in-process and over HTTP;
- protocol: rounds with Table 1's stopping rules, feasibility filter and bootstrap statistics.
bench/clutter.py runs it and writes Table-3-like results into bench/results/.
"""
