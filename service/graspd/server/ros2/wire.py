"""Bytes on the DDS wire that are ROS 2's own, not a message's: the rmw_cyclonedds service framing and the ROS 2
graph's ros_discovery_info.

Services (rmw_cyclonedds serdata.hpp, Serialization.cpp): every request and reply sample is the CDR
encapsulation (4 bytes), then the request header {client guid: u64, sequence number: i64} written in the
sample's byte order, then the request's or response's fields.  The server answers with the guid and sequence
number of the request; the client takes the replies whose guid is its own.  The fields start 16 bytes after the
encapsulation, a multiple of CDR's largest alignment (8), so the fields alone, behind an encapsulation of their
own, are the plain message: that is how they are decoded and encoded here.

Graph: a participant announces its nodes on the topic ros_discovery_info (rmw_dds_common/ParticipantEntitiesInfo:
its Gid, and per node the name, namespace and the Gids of its readers and writers; reliable, transient local,
keep last 1).  A Gid is the 16-byte DDS GUID, padded to 24 bytes in Humble.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import Any

import numpy as np

from graspd.io.ros import RosDecodeError

from .interfaces import PARTICIPANT_ENTITIES_INFO, ros_types

CDR_LE = b"\x00\x01\x00\x00"
REQUEST_HEADER_BYTES = 16


@dataclass(frozen=True)
class RequestId:
    """The rmw_cyclonedds request header: the client's request-writer instance handle and its sequence number."""

    client_guid: int
    sequence_number: int


def request_id(payload: bytes) -> RequestId:
    """The request header of a service sample, without copying the rest; RosDecodeError when absent."""
    if len(payload) < 4 + REQUEST_HEADER_BYTES or payload[0] != 0 or payload[1] not in (0, 1):
        raise RosDecodeError("request_header", f"not an rmw_cyclonedds request ({len(payload)} bytes; a CDR "
                                               "encapsulation and a 16-byte request header expected)")
    guid, seq = struct.unpack_from("<Qq" if payload[1] == 1 else ">Qq", payload, 4)
    return RequestId(guid, seq)


def split_request(payload: bytes) -> tuple[RequestId, bytes]:
    """A request sample -> (its header, the request's fields as a CDR message of their own).  RosDecodeError
    naming request_header when the sample is too short or not CDR."""
    return request_id(payload), payload[:4] + payload[4 + REQUEST_HEADER_BYTES:]


def frame_sample(request_id: RequestId, message: bytes) -> bytes:
    """A request or reply sample: the little-endian CDR message (encapsulation first) behind request_id."""
    if message[:2] != CDR_LE[:2]:
        raise ValueError("a little-endian CDR message expected")
    return CDR_LE + struct.pack("<Qq", request_id.client_guid, request_id.sequence_number) + message[4:]


def gid(guid: bytes, distro: str) -> Any:
    """An rmw_dds_common/Gid of a 16-byte DDS GUID (24 bytes, zero-padded, in Humble)."""
    store = ros_types(distro)
    size = int(store.fielddefs["rmw_dds_common/msg/Gid"][1][0][1][1][1])
    data = np.zeros(size, np.uint8)
    data[:16] = np.frombuffer(guid[:16], np.uint8)
    return store.types["rmw_dds_common/msg/Gid"](data=data)


def participant_entities_info(participant: bytes, node_name: str, namespace: str, readers: list[bytes],
                              writers: list[bytes], distro: str) -> bytes:
    """CDR rmw_dds_common/ParticipantEntitiesInfo: one node (name, namespace) with its readers' and writers'
    GUIDs, for ros_discovery_info (what `ros2 node list` and `ros2 node info` read)."""
    store = ros_types(distro)
    node = store.types["rmw_dds_common/msg/NodeEntitiesInfo"](
        node_namespace=namespace, node_name=node_name, reader_gid_seq=[gid(g, distro) for g in readers],
        writer_gid_seq=[gid(g, distro) for g in writers])
    msg = store.types[PARTICIPANT_ENTITIES_INFO](gid=gid(participant, distro), node_entities_info_seq=[node])
    return bytes(store.serialize_cdr(msg, PARTICIPANT_ENTITIES_INFO))


def service_id(participant: bytes, counter: int) -> bytes:
    """The user data "serviceid=<id>;" of a service's request reader and reply writer (rmw_cyclonedds
    get_unique_csid + csid_to_string: the participant's GUID prefix and a counter, bytes in hex, dot-separated):
    clients pair the two endpoints by it before they call the service available."""
    raw = participant[:12] + counter.to_bytes(4, "big")
    text = f"{raw[0]:2x}" + "".join(f".{b:x}" for b in raw[1:])
    return f"serviceid={text};".encode()
