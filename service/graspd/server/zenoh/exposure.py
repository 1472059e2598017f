"""What a Zenoh configuration exposes and whether it authenticates peers: the session's config from the settings
(zenoh_config) and the refusal to open Zenoh beyond loopback with nobody authenticated (check_exposure)."""

from __future__ import annotations

import ipaddress
import json
import logging
from typing import Any

from graspd.server.settings import Settings

log = logging.getLogger("graspd.server")

#: The Zenoh keys our settings fill in when GRASPD_ZENOH_CONFIG leaves them at Zenoh's defaults.
SETTINGS_KEYS = ("mode", "listen/endpoints", "connect/endpoints", "scouting/multicast/enabled")
_LOCAL_PROTOCOLS = frozenset({"unixsock-stream", "unixsock-seqpacket", "unixpipe"})


class ZenohSetupError(RuntimeError):
    """The Zenoh configuration is unusable or unsafe; the server refuses to start (names the setting)."""


def zenoh_config(settings: Settings) -> Any:
    """A zenoh.Config: the file GRASPD_ZENOH_CONFIG if set (TLS, auth, access control pass through untouched),
    then mode, listen/connect endpoints and multicast scouting from the settings for every one of those keys
    the file leaves at Zenoh's default (a key the file sets wins)."""
    import zenoh  # noqa: PLC0415

    if settings.zenoh_config is None:
        conf = zenoh.Config()
    else:
        path = settings.zenoh_config
        if not path.is_file():
            raise ZenohSetupError(f"GRASPD_ZENOH_CONFIG: {path} is not a file")
        try:
            conf = zenoh.Config.from_file(str(path))
        except Exception as exc:  # zenoh.ZError: a JSON5 syntax error or an unknown key
            raise ZenohSetupError(f"GRASPD_ZENOH_CONFIG: {path} is not a valid Zenoh config ({exc})") from None
    default = zenoh.Config()
    ours: dict[str, Any] = {"mode": settings.zenoh_mode, "listen/endpoints": list(settings.zenoh_listen),
                            "connect/endpoints": list(settings.zenoh_connect),
                            "scouting/multicast/enabled": settings.zenoh_multicast}
    for key in SETTINGS_KEYS:
        if conf.get_json(key) == default.get_json(key):
            conf.insert_json5(key, json.dumps(ours[key]))
    admin = config_value(conf, "adminspace/enabled") is True
    if settings.token is not None and not settings.zenoh_admin_space and admin:
        # the admin space (@/<zid>/**: endpoints, peers, metrics) answers any peer, token or not
        log.warning("GRASPD_ZENOH_CONFIG enables the Zenoh admin space; turned off because a token is set "
                    "(GRASPD_ZENOH_ADMIN_SPACE=true keeps it)")
        conf.insert_json5("adminspace/enabled", "false")
    return conf


def _strings(value: Any) -> list[str]:
    """Every string in a JSON value (endpoint lists may be keyed by mode: {"router": [...], "peer": [...]})."""
    if isinstance(value, str):
        return [value]
    if isinstance(value, dict):
        return [s for v in value.values() for s in _strings(v)]
    if isinstance(value, list):
        return [s for v in value for s in _strings(v)]
    return []


def is_local_endpoint(endpoint: str) -> bool:
    """Whether a Zenoh endpoint ("tcp/127.0.0.1:7447", "tls/[::1]:7447", "unixsock-stream//run/z.sock") only
    reaches this machine; a host name other than localhost, or an unspecified address, does not."""
    proto, _, rest = endpoint.partition("/")
    if proto in _LOCAL_PROTOCOLS:
        return True
    address = rest.split("?", 1)[0].split("#", 1)[0]
    host = address.rsplit(":", 1)[0].strip("[]")
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def config_value(conf: Any, key: str) -> Any:
    try:
        return json.loads(conf.get_json(key))
    except Exception:  # a key this zenoh version does not know
        return None


def exposure(conf: Any) -> list[str]:
    """What makes a Zenoh config reachable from other machines: non-loopback listen/connect endpoints,
    multicast scouting.  Empty: loopback only."""
    out = [e for key in ("listen/endpoints", "connect/endpoints") for e in _strings(config_value(conf, key))
           if not is_local_endpoint(e)]
    if config_value(conf, "scouting/multicast/enabled") is not False:
        out.append("multicast scouting")
    return out


def authenticates(conf: Any) -> bool:
    """Whether a Zenoh config authenticates peers itself: user/password, mutual TLS, or access control."""
    return (config_value(conf, "transport/auth/usrpwd/user") is not None
            or config_value(conf, "transport/link/tls/enable_mtls") is True
            or config_value(conf, "access_control/enabled") is True)


def check_exposure(settings: Settings, conf: Any) -> None:
    """Refuse (ZenohSetupError) to open Zenoh beyond loopback when nothing authenticates peers: no
    GRASPD_TOKEN, no auth in GRASPD_ZENOH_CONFIG, and no explicit GRASPD_ZENOH_ALLOW_ANONYMOUS."""
    reach = exposure(conf)
    if not reach or settings.token is not None or authenticates(conf) or settings.zenoh_allow_anonymous:
        return
    raise ZenohSetupError(
        f"Zenoh would be reachable from other machines ({', '.join(reach)}) with no authentication, so anyone "
        "there could run detections and write the template library.  Set GRASPD_TOKEN (clients send it: "
        "ZenohGraspClient(token=...)), or GRASPD_ZENOH_CONFIG with user/password, mTLS or access control, or "
        "listen on loopback (GRASPD_ZENOH_LISTEN='[\"tcp/127.0.0.1:7447\"]'); on a trusted network only, "
        "GRASPD_ZENOH_ALLOW_ANONYMOUS=true")
