"""`graspd serve`: run the HTTP app (uvicorn) with its embedded Zenoh node, and with --ros2 its ROS 2 node;
settings from GRASPD_* env variables, command-line flags override them."""

from __future__ import annotations

import argparse
from typing import Any

import uvicorn

from graspd.server.app import create_app
from graspd.server.logs import configure_logging
from graspd.server.runner import uvicorn_config
from graspd.server.services.allocator import tune_malloc
from graspd.server.settings import Settings


def register(subparsers: Any) -> None:
    """Add the `serve` subcommand to graspd's argparse subparsers."""
    p = subparsers.add_parser("serve", help="run the grasp-detection service (HTTP + Zenoh)")
    p.add_argument("--host", help="bind address (default 127.0.0.1; 0.0.0.0 in the container)")
    p.add_argument("--port", type=int, help="HTTP port (default 8000)")
    p.add_argument("--models-dir", help="folder of ONNX models with JSON cards (default: models/)")
    p.add_argument("--model", dest="default_model", help="default model name")
    p.add_argument("--workers", dest="detect_workers", type=int, help="concurrent detections (default: cores)")
    p.add_argument("--no-zenoh", dest="zenoh_enabled", action="store_false", default=None,
                   help="HTTP only")
    p.add_argument("--zenoh-listen", action="append", help="Zenoh endpoint to listen on (repeatable)")
    p.add_argument("--zenoh-connect", action="append", help="Zenoh endpoint to connect to (repeatable)")
    p.add_argument("--zenoh-instance", help="instance id under <prefix>/instances/ (several servers)")
    p.add_argument("--zenoh-config", metavar="PATH",
                   help="Zenoh JSON5 config file (TLS/mTLS, user/password, access control); keys it sets win "
                        "over --zenoh-listen/--zenoh-connect (GRASPD_ZENOH_CONFIG)")
    p.add_argument("--ros2", dest="ros2_enabled", action="store_true", default=None,
                   help="also join ROS 2 natively over DDS as the node /graspd (needs graspd[ros2]; "
                        "GRASPD_ROS2_*)")
    p.add_argument("--ros2-domain-id", type=int, help="ROS 2 domain (default ROS_DOMAIN_ID, else 0)")
    p.set_defaults(func=serve)


def settings_from_args(args: argparse.Namespace) -> Any:
    overrides = {k: getattr(args, k, None) for k in ("host", "port", "models_dir", "default_model", "detect_workers",
                                                     "zenoh_enabled", "zenoh_listen", "zenoh_connect",
                                                     "zenoh_instance", "zenoh_config", "ros2_enabled",
                                                     "ros2_domain_id")}
    return Settings(**{k: v for k, v in overrides.items() if v is not None})


def serve(args: argparse.Namespace) -> int:
    """Run until SIGINT/SIGTERM; running detections finish before the process exits."""

    tune_malloc()  # before any worker thread exists: large request buffers go back to the OS
    settings = settings_from_args(args)
    configure_logging(settings.log_level, settings.log_json)
    uvicorn.Server(uvicorn_config(create_app(settings), settings)).run()  # HTTP limits: Settings.http_*
    return 0


def main(argv: list[str] | None = None) -> int:
    """`python -m graspd.server.cli` without the graspd CLI wired in."""
    parser = argparse.ArgumentParser(prog="graspd")
    register(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(argv)
    return int(args.func(args))


if __name__ == "__main__":
    raise SystemExit(main())
