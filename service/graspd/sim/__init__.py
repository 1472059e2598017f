"""Physics-simulated dense-clutter benchmark (pybullet, DIRECT mode): scenes, depth sensing, a free-floating
parallel-jaw hand and the IJRR Table 1 protocol, for judging grasp detectors without a robot."""
