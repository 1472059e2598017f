"""The DDS participant of the ROS 2 node (cyclonedds, the optional extra graspd[ros2]): its domain configuration
(discovery range as ROS_AUTOMATIC_DISCOVERY_RANGE, sample-size cap, a user's CycloneDDS XML), DDS Security as
rmw_cyclonedds sets it up from an SROS2 enclave, the QoS profiles ROS 2 users expect, and readers and writers that
move CDR bytes (the samples are encoded and decoded by graspd.io.ros, never by cyclonedds' Python serializer, which
would build one Python int per byte of a PointCloud2)."""

from __future__ import annotations

import logging
import os
import socket
import threading
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from xml.sax.saxutils import quoteattr

import psutil
from cyclonedds.core import DDSException, InstanceState, Listener, Policy, Qos, SampleState, ViewState
from cyclonedds.domain import Domain, DomainParticipant
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.util import duration

from .errors import Ros2SetupError
from .interfaces import idl_type

#: The files of an SROS2 enclave (ros2 security create_enclave) -> the participant QoS property each goes to
#: (rmw_cyclonedds: configure_qos_for_security); crl.pem is optional.
SECURITY_FILES: dict[str, str] = {"identity_ca.cert.pem": "dds.sec.auth.identity_ca",
                                  "cert.pem": "dds.sec.auth.identity_certificate",
                                  "key.pem": "dds.sec.auth.private_key",
                                  "permissions_ca.cert.pem": "dds.sec.access.permissions_ca",
                                  "governance.p7s": "dds.sec.access.governance",
                                  "permissions.p7s": "dds.sec.access.permissions"}
#: The security plugins: (QoS property prefix, library name, init, finalize).
SECURITY_PLUGINS: tuple[tuple[str, str, str, str], ...] = (
    ("dds.sec.auth", "dds_security_auth", "init_authentication", "finalize_authentication"),
    ("dds.sec.crypto", "dds_security_crypto", "init_crypto", "finalize_crypto"),
    ("dds.sec.access", "dds_security_ac", "init_access_control", "finalize_access_control"))
_ANY_STATE = SampleState.Any | ViewState.Any | InstanceState.Any
#: The loopback interface's name (Linux), and the addresses of a socket that listens on every interface.
LOOPBACK_DEVICE = "lo"
WILDCARD = ("0.0.0.0", "::")
log = logging.getLogger("graspd.server")
#: Participants are made one at a time: the sockets a new one opened are told from the others by a before/after
#: list of this process's sockets.
_CREATE_LOCK = threading.Lock()


@dataclass(frozen=True)
class DomainConfig:
    """What the participant is made with: domain id, the CycloneDDS XML fragments (comma-joined, later ones win),
    and the participant QoS (user data "enclave=...;" and, with an enclave, the DDS Security properties)."""

    domain_id: int
    xml: str
    qos: Qos
    #: Restrict the participant's receive sockets to the loopback interface (Linux SO_BINDTODEVICE): Cyclone
    #: binds them to 0.0.0.0 whatever its interfaces; strict: refuse the participant when that cannot be done.
    loopback_only: bool = False
    loopback_strict: bool = True


def discovery_xml(discovery: str, peers: list[str], interfaces: list[str], max_sample_bytes: int,
                  socket_buffer_bytes: int | None = None) -> str:
    """The CycloneDDS XML of a discovery range, as rmw_cyclonedds builds it for ROS_AUTOMATIC_DISCOVERY_RANGE:
    "localhost" (no multicast, localhost as a static peer, and here also only the loopback interface: nothing
    beyond this machine can reach the node), "subnet" (Cyclone's defaults: multicast on the default interface),
    "off" (no discovery but the static peers); peers are added in every range.  Samples larger than
    max_sample_bytes are dropped by DDS itself (Internal/MaxSampleSize), in and out.  socket_buffer_bytes: the
    UDP receive buffer to insist on (Internal/SocketReceiveBufferSize min; the kernel's net.core.rmem_max must
    allow it, else the participant is refused): a best-effort cloud of megabytes arrives as thousands of
    fragments at once, and one lost fragment loses the cloud."""
    general = ""
    if discovery == "localhost":
        general = ('<Interfaces><NetworkInterface address="127.0.0.1" multicast="false"/></Interfaces>'
                   "<AllowMulticast>false</AllowMulticast>")
    elif discovery == "off":
        general = "<AllowMulticast>false</AllowMulticast>"
    elif interfaces:
        general = "<Interfaces>" + "".join(f"<NetworkInterface name={quoteattr(i)}/>" for i in interfaces) + \
            "</Interfaces>"
    all_peers = (["localhost"] if discovery == "localhost" else []) + list(peers)
    disco = "<ParticipantIndex>auto</ParticipantIndex><MaxAutoParticipantIndex>32</MaxAutoParticipantIndex>"
    if all_peers:
        disco += "<Peers>" + "".join(f"<Peer address={quoteattr(p)}/>" for p in all_peers) + "</Peers>"
    internal = f"<MaxSampleSize>{int(max_sample_bytes)}B</MaxSampleSize>"
    if socket_buffer_bytes:
        internal += f'<SocketReceiveBufferSize min="{int(socket_buffer_bytes)}B"/>'
    internal = f"<Internal>{internal}</Internal>"
    return (f"<CycloneDDS><Domain><General>{general}</General><Discovery>{disco}</Discovery>{internal}"
            "</Domain></CycloneDDS>")


def security_properties(enclave: Path, plugins_dir: Path | None = None) -> dict[str, str]:
    """The participant QoS properties of DDS Security from an SROS2 enclave folder (identity_ca.cert.pem,
    cert.pem, key.pem, permissions_ca.cert.pem, governance.p7s, permissions.p7s, optional crl.pem), exactly as
    rmw_cyclonedds sets them ("file:" URIs); the plugin libraries by name (the dynamic loader finds them), or in
    plugins_dir.  Ros2SetupError naming the missing file."""
    if not enclave.is_dir():
        raise Ros2SetupError(f"GRASPD_ROS2_SECURITY_ENCLAVE: {enclave} is not a folder (an SROS2 enclave: "
                             "ros2 security create_enclave <keystore> /graspd)")
    props: dict[str, str] = {}
    for name, key in SECURITY_FILES.items():
        path = enclave / name
        if not path.is_file():
            raise Ros2SetupError(f"GRASPD_ROS2_SECURITY_ENCLAVE: {enclave} lacks {name}")
        props[key] = f"file:{path.resolve()}"
    if (enclave / "crl.pem").is_file():
        props["org.eclipse.cyclonedds.sec.auth.crl"] = f"file:{(enclave / 'crl.pem').resolve()}"
    for prefix, library, init, finalize in SECURITY_PLUGINS:
        props[f"{prefix}.library.path"] = library if plugins_dir is None else str(plugins_dir / f"lib{library}.so")
        props[f"{prefix}.library.init"] = init
        props[f"{prefix}.library.finalize"] = finalize
    return props


def participant_qos(enclave_name: str, properties: dict[str, str]) -> Qos:
    """Participant QoS: user data "enclave=<name>;" (what rmw_cyclonedds announces) plus the given properties."""
    policies: list[Any] = [Policy.Userdata(f"enclave={enclave_name};".encode())]
    policies += [Policy.Property(key=k, value=v) for k, v in properties.items()]
    return Qos(*policies)


# ------------------------------------------------------------------------------------------------ QoS profiles
def sensor_qos(depth: int = 5) -> Qos:
    """rclcpp SensorDataQoS: best effort, volatile, keep last depth (clouds; a late cloud is worth nothing)."""
    return Qos(Policy.Reliability.BestEffort, Policy.Durability.Volatile, Policy.History.KeepLast(depth))


def reliable_qos(depth: int = 10, user_data: bytes | None = None) -> Qos:
    """ROS 2's default (and services') QoS: reliable, volatile, keep last depth; optional endpoint user data."""
    policies: list[Any] = [Policy.Reliability.Reliable(duration(seconds=1)), Policy.Durability.Volatile,
                           Policy.History.KeepLast(depth)]
    if user_data is not None:
        policies.append(Policy.Userdata(user_data))
    return Qos(*policies)


def latched_qos() -> Qos:
    """ros_discovery_info's QoS: reliable, transient local, keep last 1 (late joiners get the node's entities)."""
    return Qos(Policy.Reliability.Reliable(duration(seconds=1)), Policy.Durability.TransientLocal,
               Policy.History.KeepLast(1))


# ------------------------------------------------------------------------------------------ readers, writers
class Participant:
    """One DDS domain (made with the DomainConfig's XML) and participant; topics are made once per name."""

    def __init__(self, config: DomainConfig) -> None:
        with _CREATE_LOCK:
            before = wildcard_udp_sockets() if config.loopback_only else set()
            self._create(config)
            #: the participant's sockets that listen on every interface and were restricted to loopback (fds)
            self.bound_to_loopback: set[int] = set()
            if config.loopback_only:
                self._bind_loopback(wildcard_udp_sockets() - before, config)
        self._topics: dict[str, Topic[Any]] = {}

    def _bind_loopback(self, fds: set[int], config: DomainConfig) -> None:
        try:
            bind_to_loopback(fds)
            self.bound_to_loopback = fds
        except OSError as exc:
            message = (f"ROS 2 domain {config.domain_id}: cannot restrict the DDS sockets to the loopback interface "
                       f"({exc}): they listen on every interface")
            if config.loopback_strict:
                _delete(self.dp)
                _delete(self.domain)
                raise Ros2SetupError(f"{message}.  Run on Linux 5.7 or later (or with CAP_NET_RAW), or accept it "
                                     "with GRASPD_ROS2_ALLOW_ANONYMOUS=true (trusted networks only)") from None
            log.warning(message)

    def _create(self, config: DomainConfig) -> None:
        try:
            self.domain = Domain(config.domain_id, config.xml)
        except DDSException as exc:
            raise Ros2SetupError(f"ROS 2 domain {config.domain_id}: the DDS configuration is refused ({exc}); "
                                 "check GRASPD_ROS2_CONFIG and GRASPD_ROS2_PEERS") from None
        try:
            self.dp = DomainParticipant(config.domain_id, qos=config.qos)
        except DDSException as exc:
            secure = any(getattr(p, "key", "").startswith("dds.sec.") for p in config.qos)
            hint = (" DDS Security is configured: the cyclonedds wheel ships no security plugins "
                    "(libdds_security_auth/_ac/_crypto); build Cyclone DDS with ENABLE_SECURITY and OpenSSL, and "
                    "point GRASPD_ROS2_SECURITY_PLUGINS at them") if secure else ""
            raise Ros2SetupError(f"ROS 2 domain {config.domain_id}: no DDS participant ({exc}).{hint}") from None

    def topic(self, name: str, ros_type: str, distro: str) -> Topic[Any]:
        """The DDS topic name (rt/..., rq/..., rr/...) of ros_type (made once)."""
        if name not in self._topics:
            self._topics[name] = Topic(self.dp, name, idl_type(ros_type, distro))
        return self._topics[name]

    @property
    def guid(self) -> bytes:
        """The participant's 16-byte DDS GUID (a ROS 2 graph Gid)."""
        return self.dp.guid.bytes

    def close(self, endpoints: list[Any] | None = None) -> None:
        """Delete the endpoints (RawReader, RawWriter; their listeners stop first), the topics, the participant,
        then the domain, in that order: cyclonedds' Python objects do not delete their DDS entity when collected,
        and a listener freed before its reader would be called after it is gone."""
        for endpoint in endpoints or []:
            endpoint.close()
        for entity in (*self._topics.values(), self.dp, self.domain):
            _delete(entity)
        self._topics.clear()


class RawWriter:
    """A DataWriter of CDR bytes (4-byte encapsulation header first, as graspd.io.ros and rosbags produce them)."""

    def __init__(self, participant: Participant, name: str, ros_type: str, distro: str, qos: Qos) -> None:
        from cyclonedds._clayer import ddspy_write  # noqa: PLC0415 - the raw write of cyclonedds' Python layer

        self._write = ddspy_write
        self.name = name
        self.writer = DataWriter(participant.dp, participant.topic(name, ros_type, distro), qos=qos)
        self._lock = threading.Lock()

    @property
    def guid(self) -> bytes:
        return self.writer.guid.bytes

    def write(self, payload: bytes) -> None:
        """Publish one sample (padded to a multiple of 4 bytes, as cyclonedds' own serializer does)."""
        pad = -len(payload) % 4
        data = payload + b"\0" * pad if pad else payload
        with self._lock:
            ret = self._write(self.writer._ref, data)
        if ret < 0:
            raise DDSException(ret, f"writing a sample on {self.name}")

    def matched(self) -> int:
        """Readers matched now."""
        return len(self.writer.get_matched_subscriptions())

    def close(self) -> None:
        """Delete the DDS writer."""
        _delete(self.writer)


class RawReader:
    """A DataReader that hands each sample's CDR bytes to on_sample(bytes) on Cyclone's listener thread (which
    must return at once: the node only copies the bytes to its queue there)."""

    def __init__(self, participant: Participant, name: str, ros_type: str, distro: str, qos: Qos,
                 on_sample: Callable[[bytes], None]) -> None:
        from cyclonedds._clayer import ddspy_take  # noqa: PLC0415 - the raw take of cyclonedds' Python layer

        self._take = ddspy_take
        self.name = name
        self.on_sample = on_sample
        self.reader: DataReader[Any] | None = None
        self.reader = DataReader(participant.dp, participant.topic(name, ros_type, distro), qos=qos,
                                 listener=Listener(on_data_available=self._available))
        self._available(None)  # what arrived while the reader was being made (transient local data)

    @property
    def guid(self) -> bytes:
        assert self.reader is not None
        return self.reader.guid.bytes

    def _available(self, _entity: Any) -> None:
        reader = self.reader  # None while DataReader() runs: its first data is taken right after
        if reader is None:
            return
        while True:
            got = self._take(reader._ref, _ANY_STATE, 8)
            if isinstance(got, int) or not got:
                return
            for data, info in got:
                if info.valid_data:
                    self.on_sample(data)

    def matched(self) -> int:
        """Writers matched now."""
        return 0 if self.reader is None else len(self.reader.get_matched_publications())

    def close(self) -> None:
        """Delete the DDS reader (its listener is not called after this returns)."""
        reader, self.reader = self.reader, None
        if reader is not None:
            _delete(reader)


def wildcard_udp_sockets() -> set[int]:
    """File descriptors of this process's UDP sockets bound to every interface (0.0.0.0 or ::)."""
    return {c.fd for c in psutil.Process().net_connections(kind="udp") if c.laddr and c.laddr.ip in WILDCARD}


def bind_to_loopback(fds: set[int]) -> None:
    """Let the sockets fds receive only what arrives on the loopback interface (SO_BINDTODEVICE "lo": Linux,
    unprivileged since 5.7 for a socket not yet bound to a device).  OSError when the system refuses it."""
    option = getattr(socket, "SO_BINDTODEVICE", None)
    if option is None:
        raise OSError("SO_BINDTODEVICE is Linux only")
    for fd in fds:
        with socket.socket(fileno=os.dup(fd)) as sock:  # the same socket; closing the duplicate leaves it open
            sock.setsockopt(socket.SOL_SOCKET, option, LOOPBACK_DEVICE.encode())


def socket_device(fd: int) -> str:
    """The interface a socket is restricted to (SO_BINDTODEVICE), "" when none."""
    option = getattr(socket, "SO_BINDTODEVICE", None)
    if option is None:
        return ""
    with socket.socket(fileno=os.dup(fd)) as sock:
        return sock.getsockopt(socket.SOL_SOCKET, option, 16).split(b"\0", 1)[0].decode()


def _delete(entity: Any) -> None:
    """dds_delete of a cyclonedds entity, once (an entity already deleted with its parent is skipped)."""
    try:
        entity.__del__()
    except Exception:  # already gone with its parent
        pass
