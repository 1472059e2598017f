"""graspd.io: formats at the edge: cloud files (PCD, PLY, NPY/NPZ, depth images), ROS CDR messages, PNG, mesh
headers.  Translates them into graspd.core values once; imports only graspd.core."""
