"""DDS Security and exposure of the ROS 2 node: the settings of an SROS2 enclave reach the participant's QoS as the
properties rmw_cyclonedds sets (governance and permissions included, "file:" URIs) and DDS acts on them (it loads
the security plugins, and refuses the participant when they are absent, which the server reports naming the
plugins); a node reachable beyond this machine without security is refused; the default participant's sockets
receive only on the loopback interface (checked on the sockets of a child process) and a local process still
reaches it; GRASPD_ROS2_* and ROS_DOMAIN_ID reach the settings.

Finding: the cyclonedds wheel from PyPI builds libddsc with security support but ships no security plugins
(libdds_security_auth, _ac, _crypto; they need OpenSSL), so a secured participant cannot be made with the wheel
alone: test_the_wheel_ships_no_security_plugins records it (and fails the day a wheel ships them, so that a
real handshake test can be added)."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import cyclonedds
import pytest
from cyclonedds.core import Policy
from fastapi.testclient import TestClient

from graspd.server.app import create_app
from graspd.server.ros2.dds import SECURITY_FILES, Participant, RawWriter, reliable_qos
from graspd.server.ros2.errors import Ros2SetupError
from graspd.server.ros2.interfaces import ros_types
from graspd.server.ros2.node import domain_config
from graspd.server.settings import Settings

from .conftest import next_domain


def enclave(tmp_path: Path, skip: str | None = None) -> Path:
    """An SROS2 enclave's file layout (contents are placeholders: no plugin reads them here)."""
    folder = tmp_path / "keystore" / "enclaves" / "graspd"
    folder.mkdir(parents=True)
    for name in SECURITY_FILES:
        if name != skip:
            (folder / name).write_text(f"placeholder {name}\n")
    return folder


def settings(tmp_path: Path, **overrides: object) -> Settings:
    base: dict[str, object] = {"zenoh_enabled": False, "ros2_enabled": True, "ros2_domain_id": next_domain(),
                               "models_dir": tmp_path / "no-models", "data_dir": tmp_path / "data",
                               "allow_unscored": True, "warmup": False, "detect_workers": 1}
    return Settings(**{**base, **overrides})  # type: ignore[arg-type]


def plugins_shipped() -> bool:
    roots = [Path(cyclonedds.__file__).parent, Path(cyclonedds.__file__).parent.parent / "cyclonedds.libs"]
    return any(any(root.glob("*dds_security_auth*")) for root in roots if root.exists())


def test_the_wheel_ships_no_security_plugins() -> None:
    assert not plugins_shipped(), "the cyclonedds wheel now ships the security plugins: add a handshake test"


def test_the_enclave_reaches_the_participant_qos(tmp_path: Path) -> None:
    folder = enclave(tmp_path)
    config = domain_config(settings(tmp_path, ros2_security_enclave=folder, ros2_security_plugins=tmp_path / "p"))
    props = {p.key: p.value for p in config.qos if isinstance(p, Policy.Property)}
    assert props["dds.sec.access.governance"] == f"file:{folder.resolve() / 'governance.p7s'}"
    assert props["dds.sec.access.permissions"] == f"file:{folder.resolve() / 'permissions.p7s'}"
    assert props["dds.sec.auth.identity_ca"].endswith("identity_ca.cert.pem")
    assert props["dds.sec.auth.private_key"].endswith("key.pem")
    assert props["dds.sec.auth.library.path"] == str(tmp_path / "p" / "libdds_security_auth.so")
    assert props["dds.sec.crypto.library.init"] == "init_crypto"
    assert [p.data for p in config.qos if isinstance(p, Policy.Userdata)] == [b"enclave=/;"]


@pytest.mark.skipif(plugins_shipped(), reason="security plugins present: the participant would be made")
def test_dds_acts_on_the_enclave_and_the_server_refuses_to_start_without_plugins(tmp_path: Path) -> None:
    with pytest.raises(Ros2SetupError, match="security plugins") as err:
        with TestClient(create_app(settings(tmp_path, ros2_security_enclave=enclave(tmp_path)))):
            pass
    assert "GRASPD_ROS2_SECURITY_PLUGINS" in str(err.value)


def test_an_incomplete_enclave_is_refused_naming_the_file(tmp_path: Path) -> None:
    with pytest.raises(Ros2SetupError, match=r"lacks permissions\.p7s"):
        domain_config(settings(tmp_path, ros2_security_enclave=enclave(tmp_path, skip="permissions.p7s")))


def test_the_node_is_loopback_only_unless_secured_or_explicitly_anonymous(tmp_path: Path) -> None:
    local = domain_config(settings(tmp_path))
    assert '<NetworkInterface address="127.0.0.1" multicast="false"/>' in local.xml
    assert "<AllowMulticast>false</AllowMulticast>" in local.xml and '<Peer address="localhost"/>' in local.xml
    assert local.loopback_only and local.loopback_strict
    for reach in ({"ros2_discovery": "subnet"}, {"ros2_peers": ["10.0.0.7"]}):
        with pytest.raises(Ros2SetupError, match="GRASPD_ROS2_SECURITY_ENCLAVE"):
            domain_config(settings(tmp_path, **reach))
    open_ = domain_config(settings(tmp_path, ros2_discovery="subnet", ros2_allow_anonymous=True))
    assert "127.0.0.1" not in open_.xml and "AllowMulticast" not in open_.xml and not open_.loopback_only
    secured = domain_config(settings(tmp_path, ros2_discovery="subnet", ros2_security_enclave=enclave(tmp_path)))
    assert any(isinstance(p, Policy.Property) for p in secured.qos)


def test_a_cyclonedds_xml_file_is_laid_over_and_the_size_cap_follows_the_body_cap(tmp_path: Path) -> None:
    xml = tmp_path / "cyclonedds.xml"
    xml.write_text("<CycloneDDS><Domain><Tracing><Verbosity>warning</Verbosity></Tracing></Domain></CycloneDDS>")
    config = domain_config(settings(tmp_path, ros2_config=xml, ros2_allow_anonymous=True, max_body_bytes=1000))
    assert config.xml.endswith(f",file://{xml.resolve()}") and "<MaxSampleSize>2000B</MaxSampleSize>" in config.xml


def test_environment_variables_reach_the_settings(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("ROS_DOMAIN_ID", "42")
    assert Settings().ros2_domain_id == 42
    monkeypatch.setenv("GRASPD_ROS2_DOMAIN_ID", "17")
    monkeypatch.setenv("GRASPD_ROS2_SECURITY_ENCLAVE", str(tmp_path))
    monkeypatch.setenv("GRASPD_ROS2_TOPICS", '{"pointcloud2": "/camera/depth/points", "plan_grasps": ""}')
    s = Settings()
    assert (s.ros2_domain_id, s.ros2_security_enclave) == (17, tmp_path)
    assert s.ros2_topics == {"pointcloud2": "/camera/depth/points", "plan_grasps": ""}


def test_serve_ros2_flags_reach_the_settings() -> None:
    import argparse  # noqa: PLC0415

    from graspd.server.cli import register, settings_from_args  # noqa: PLC0415

    parser = argparse.ArgumentParser()
    register(parser.add_subparsers(dest="command"))
    s = settings_from_args(parser.parse_args(["serve", "--ros2", "--ros2-domain-id", "5"]))
    assert (s.ros2_enabled, s.ros2_domain_id) == (True, 5)
    assert settings_from_args(parser.parse_args(["serve"])).ros2_enabled is False


#: A child process that makes the node's participant (domain_config of the default settings, or with the
#: loopback restriction left out: "unbound"), prints its UDP sockets as [address, port, device] and, with
#: "listen", waits up to 20 s for a std_msgs/String on rt/graspd_probe and prints "received".
PARTICIPANT = """
import json, sys, time
from dataclasses import replace
from pathlib import Path
import psutil
from graspd.server.ros2.dds import Participant, RawReader, reliable_qos, socket_device
from graspd.server.ros2.node import domain_config
from graspd.server.settings import Settings
domain, folder, mode = int(sys.argv[1]), Path(sys.argv[2]), sys.argv[3]
config = domain_config(Settings(ros2_domain_id=domain, zenoh_enabled=False, models_dir=folder, data_dir=folder))
p = Participant(config if mode != "unbound" else replace(config, loopback_only=False))
print(json.dumps([[c.laddr.ip, c.laddr.port, socket_device(c.fd)]
                  for c in psutil.Process().net_connections(kind="udp")]), flush=True)
if mode == "listen":
    got = []
    reader = RawReader(p, "rt/graspd_probe", "std_msgs/msg/String", "jazzy", reliable_qos(), got.append)
    end = time.monotonic() + 20
    while not got and time.monotonic() < end:
        time.sleep(0.05)
    print("received" if got else "nothing", flush=True)
    reader.close()
p.close()
"""


def participant(tmp_path: Path, domain: int, mode: str) -> subprocess.Popen[str]:
    return subprocess.Popen([sys.executable, "-c", PARTICIPANT, str(domain), str(tmp_path), mode],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def sockets_of(tmp_path: Path, domain: int, mode: str) -> list[tuple[str, int, str]]:
    out, _ = participant(tmp_path, domain, mode).communicate(timeout=60)
    return [(ip, port, device) for ip, port, device in json.loads(out.splitlines()[0])]


def test_the_default_participant_receives_only_on_loopback(tmp_path: Path) -> None:
    domain = next_domain()
    bound = sockets_of(tmp_path, domain, "default")
    assert bound and all(ip == "127.0.0.1" or device == "lo" for ip, _, device in bound), bound
    assert 7400 + 250 * domain not in {port for _, port, _ in bound}  # no multicast discovery socket
    # what the node changes: Cyclone binds its receive sockets to 0.0.0.0 whatever its interfaces
    unbound = sockets_of(tmp_path, domain, "unbound")
    assert any(ip == "0.0.0.0" and not device for ip, _, device in unbound), unbound


def test_a_local_process_still_reaches_the_loopback_only_participant(tmp_path: Path) -> None:
    domain = next_domain()
    child = participant(tmp_path, domain, "listen")
    config = domain_config(settings(tmp_path, ros2_domain_id=domain))
    peer = Participant(replace(config, loopback_only=False))  # as ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
    store = ros_types("jazzy")
    hello = bytes(store.serialize_cdr(store.types["std_msgs/msg/String"](data="hello"), "std_msgs/msg/String"))
    writer = RawWriter(peer, "rt/graspd_probe", "std_msgs/msg/String", "jazzy", reliable_qos())
    try:
        end = time.monotonic() + 30
        while child.poll() is None and time.monotonic() < end:
            if writer.matched():
                writer.write(hello)
            time.sleep(0.1)
        out, err = child.communicate(timeout=30)
    finally:
        peer.close([writer])
    assert out.splitlines()[-1] == "received", (out, err)
