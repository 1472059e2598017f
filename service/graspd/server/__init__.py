"""The networked service: FastAPI app, Zenoh node and serve CLI, thin adapters over one GraspDetector."""
