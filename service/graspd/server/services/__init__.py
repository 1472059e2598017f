"""graspd.server.services: what the transports share: the detection engine, the model registry, template and
instance-model jobs, admission (budget, allocator), proposals and start-up warm-up."""
