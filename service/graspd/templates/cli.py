"""`graspd templates ...`: teach, detect, report outcomes and list the grasp library from the shell.

    graspd templates demonstrate CLOUD --pose 16 numbers (row-major 4x4) [--label L] [--library URL]
    graspd templates detect CLOUD [--max-grasps N] [--workspace ...] [--library URL] [--out grasps.json]
    graspd templates feedback GRASP_ID (--success | --failure) [--library URL]
    graspd templates library [--library URL]

The library URL defaults to $GRASPD_TEMPLATE_LIBRARY, else sqlite:///graspd-templates.db.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from typing import Any

import numpy as np

from .store import DEFAULT_URL


def _library(args: argparse.Namespace) -> Any:
    from .store import TemplateLibrary

    return TemplateLibrary(args.library or os.environ.get("GRASPD_TEMPLATE_LIBRARY", DEFAULT_URL))


def _cloud(args: argparse.Namespace) -> Any:
    from ..cloud_io import read_cloud

    vps = None if args.viewpoint is None else np.asarray(args.viewpoint, np.float32).reshape(-1, 3)
    return read_cloud(args.cloud, vps)


def _fail(exc: Exception) -> int:
    print(f"error: {exc}", file=sys.stderr)
    return 2


def _demonstrate(args: argparse.Namespace) -> int:
    from ..cloud import CloudError
    from .geometry import TemplateError

    try:
        pose = np.asarray(args.pose, np.float64).reshape(4, 4)
        entry = _library(args).add_demonstration(_cloud(args), pose, label=args.label)
    except (TemplateError, CloudError, OSError) as exc:
        return _fail(exc)
    print(json.dumps({"entry_id": entry}))
    return 0


def _detect(args: argparse.Namespace) -> int:
    from ..cloud import CloudError
    from .detector import TemplateDetector
    from .geometry import TemplateError

    workspace = None if args.workspace is None else tuple(args.workspace)
    try:
        det = TemplateDetector(_library(args)).detect(_cloud(args), max_grasps=args.max_grasps, workspace=workspace)
    except (TemplateError, CloudError, OSError) as exc:
        return _fail(exc)
    text = json.dumps(det.to_dict(), indent=1)
    if args.out:
        with open(args.out, "w") as f:
            f.write(text)
        print(f"{len(det.grasps)} grasps from {det.num_candidates} candidate templates and {det.num_entries} "
              f"library entries in {det.timings['total']:.2f} s; wrote {args.out}")
    else:
        print(text)
    return 0


def _feedback(args: argparse.Namespace) -> int:
    from .geometry import TemplateError

    try:
        fb = _library(args).add_feedback(args.grasp_id, success=bool(args.success))
    except TemplateError as exc:
        return _fail(exc)
    print(json.dumps(fb.to_dict()))
    return 0


def _summary(args: argparse.Namespace) -> int:
    print(json.dumps(_library(args).summary(), indent=1))
    return 0


def register(subparsers: Any) -> None:
    """Add the `templates` subcommand (and its own subcommands) to graspd's argparse subparsers."""
    p = subparsers.add_parser("templates", help="grasp templates from demonstrations (Herzog et al.)",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="templates_command", required=True)

    def common(q: argparse.ArgumentParser, cloud: bool) -> None:
        q.add_argument("--library", help="SQLAlchemy URL (default $GRASPD_TEMPLATE_LIBRARY or " + DEFAULT_URL + ")")
        if cloud:
            q.add_argument("cloud", help="point cloud file (.pcd, .ply, .npz) of the table and one object")
            q.add_argument("--viewpoint", type=float, nargs=3, action="extend", metavar=("X", "Y", "Z"),
                           help="camera position in the cloud frame (m); repeat for several cameras")

    d = sub.add_parser("demonstrate", help="add a demonstrated grasp to the library")
    common(d, True)
    d.add_argument("--pose", type=float, nargs=16, required=True,
                   help="hand pose, row-major 4x4: rotation columns approach, binormal, axis; base centre")
    d.add_argument("--label")
    d.set_defaults(func=_demonstrate)
    t = sub.add_parser("detect", help="grasps by template matching against the library")
    common(t, True)
    t.add_argument("--max-grasps", type=int, default=20)
    t.add_argument("--workspace", type=float, nargs=6, metavar=("XMIN", "XMAX", "YMIN", "YMAX", "ZMIN", "ZMAX"))
    t.add_argument("--out", help="write the JSON result here (else print it)")
    t.set_defaults(func=_detect)
    f = sub.add_parser("feedback", help="report the outcome of an executed grasp by its id")
    common(f, False)
    f.add_argument("grasp_id")
    g = f.add_mutually_exclusive_group(required=True)
    g.add_argument("--success", dest="success", action="store_true")
    g.add_argument("--failure", dest="success", action="store_false")
    f.set_defaults(func=_feedback)
    s = sub.add_parser("library", help="print the library summary (entries, failures, outcomes)")
    common(s, False)
    s.set_defaults(func=_summary)
