"""The wire contract of the service: pydantic models of what the transports send and receive (detect request and
response, the models and template endpoints, the error body), importing nothing of graspd above graspd.core.
The mapping to and from the detector's types is graspd.server.services.mapping."""
