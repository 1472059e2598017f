"""`graspd templates ...`: teach, detect, report outcomes and list the grasp library from the shell.

    graspd templates demonstrate CLOUD --pose 16 numbers (row-major 4x4) [--label L] [--library URL]
    graspd templates detect CLOUD [--max-grasps N] [--workspace ...] [--library URL] [--out grasps.json]
    graspd templates feedback GRASP_ID (--success | --failure) [--library URL]
    graspd templates library [--library URL]

The library is the server's (graspd.server.settings.Settings, so both open the same one by default):
--library, else $GRASPD_TEMPLATE_LIBRARY, else sqlite:///<data dir>/templates.db ($GRASPD_DATA_DIR, else
$XDG_DATA_HOME/graspd, else ~/.local/share/graspd).  A new library is made for $GRASPD_TEMPLATE_HAND (a hand
preset) as the server's is.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

from graspd.core.cloud import CloudError, ViewpointCloud
from graspd.core.hand import hand_preset
from graspd.io.cloud_files import read_cloud
from graspd.server.settings import Settings
from graspd.templates.detector import TemplateDetector
from graspd.templates.geometry import TemplateError
from graspd.templates.library import TemplateLibrary


def library_url(args: argparse.Namespace, settings: Settings | None = None) -> str:
    """--library, else the server's template library (Settings.resolved_template_library)."""
    return str(args.library or (settings or Settings()).resolved_template_library())


def _library(args: argparse.Namespace) -> TemplateLibrary:
    """The library the server would open (its folder created for an SQLite file, as the server does)."""
    settings = Settings()
    url = library_url(args, settings)
    if url.startswith("sqlite:///") and url != "sqlite:///:memory:":
        Path(url.removeprefix("sqlite:///")).parent.mkdir(parents=True, exist_ok=True)
    hand = None if settings.template_hand is None else hand_preset(settings.template_hand)
    return TemplateLibrary(url, hand=hand)


def _cloud(args: argparse.Namespace) -> ViewpointCloud:
    vps = None if args.viewpoint is None else np.asarray(args.viewpoint, np.float32).reshape(-1, 3)
    return read_cloud(args.cloud, vps)


def _fail(exc: Exception) -> int:
    print(f"error: {exc}", file=sys.stderr)
    return 2


def _demonstrate(args: argparse.Namespace) -> int:
    try:
        pose = np.asarray(args.pose, np.float64).reshape(4, 4)
        entry = _library(args).add_demonstration(_cloud(args), pose, label=args.label)
    except (TemplateError, CloudError, OSError) as exc:
        return _fail(exc)
    print(json.dumps({"entry_id": entry}))
    return 0


def _detect(args: argparse.Namespace) -> int:
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
        q.add_argument("--library", help="SQLAlchemy URL (default: the server's, $GRASPD_TEMPLATE_LIBRARY or "
                                         "sqlite:///<data dir>/templates.db)")
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
