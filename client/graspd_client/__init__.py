"""graspd-client: the robot side of graspd (numpy + httpx; zenoh optional) and the wire contract."""

from .codec import WIRE_DTYPES, WireError, decode_array, encode_array
from .errors import GraspdError, RequestRejected, ServerBusy, ServerError, TransportError
from .grasps import Grasp, Grasps
from .http import AsyncGraspClient, GraspClient
from .wire import build_demonstration_request, build_detect_request, build_feedback_request

__version__ = "0.1.0"


def __getattr__(name: str) -> object:
    if name in ("ZenohGraspClient", "AsyncZenohGraspClient"):  # imported lazily: zenoh is an optional extra
        from . import zenoh_client  # noqa: PLC0415

        return getattr(zenoh_client, name)
    raise AttributeError(name)


__all__ = [
    "WIRE_DTYPES", "AsyncGraspClient", "AsyncZenohGraspClient", "Grasp", "GraspClient", "GraspdError", "Grasps",
    "RequestRejected", "ServerBusy", "ServerError", "TransportError", "WireError", "ZenohGraspClient",
    "build_demonstration_request", "build_detect_request", "build_feedback_request", "decode_array",
    "encode_array",
]
