"""graspd detect's target flags: what to grasp (--target-mask, --target-box, --target-object, --target-indices)
and --max-per-object, parsed as the service parses a request's target (graspd.server.wire.detect.TargetSpec: the same
limits, a PNG mask checked before it is decoded, indices and masks over the rows of the file as read, NaN rows
included) and mapped onto the rows the detector keeps.  Imports stay inside the functions (fast --help)."""

# ruff: noqa: PLC0415 -- the heavy imports live in the functions that need them (fast --help)

from __future__ import annotations

import argparse
import base64
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from graspd.gpd.target import Target
    from graspd.io.inputs import CloudInput

#: The flag of each target kind (what an error names).
FLAGS = {"indices": "--target-indices", "mask": "--target-mask", "box": "--target-box", "object": "--target-object"}
#: Most bytes of a --target-mask PNG or a --target-indices file read.
MAX_TARGET_FILE_BYTES = 64 << 20


def add_target_arguments(parser: argparse.ArgumentParser) -> None:
    """The target flags (one at a time) and --max-per-object of graspd detect."""
    group = parser.add_mutually_exclusive_group()
    group.add_argument("--target-mask", metavar="PNG",
                       help="grasp what this mask covers: a PNG the size of the organised cloud or depth image "
                            "(nonzero pixels; the way segmentation models write masks)")
    group.add_argument("--target-box", type=float, nargs=10,
                       metavar=("CX", "CY", "CZ", "QX", "QY", "QZ", "QW", "HX", "HY", "HZ"),
                       help="grasp what lies in this oriented box: centre (m), rotation as a unit quaternion x y z w, "
                            "half extents (m), in the frame detection runs in (the robot frame with --camera-pose)")
    group.add_argument("--target-object", type=int, metavar="K",
                       help="grasp object K of the answer's objects (ids are the same for the same cloud)")
    group.add_argument("--target-indices", metavar="FILE",
                       help="grasp these rows of the cloud (0-based, NaN rows counted): a .npy of integers or a text "
                            "file of integers separated by spaces, commas or new lines")
    parser.add_argument("--max-per-object", type=int, metavar="N",
                        help="most grasps one object gets before every other object has one (0 = pure ranking; "
                             "default the service's)")


def _read(path: str, flag: str) -> bytes:
    p = Path(path)
    if p.stat().st_size > MAX_TARGET_FILE_BYTES:
        raise ValueError(f"{flag} {p.name}: larger than {MAX_TARGET_FILE_BYTES} bytes")
    return p.read_bytes()


def _indices(path: str) -> list[int]:
    """The integers of a --target-indices file (.npy, or text)."""
    import io

    import numpy as np

    data = _read(path, FLAGS["indices"])
    if Path(path).suffix.lower() == ".npy":
        values = np.load(io.BytesIO(data), allow_pickle=False)
        if values.dtype.kind not in "iu":
            raise ValueError(f"{FLAGS['indices']}: integer rows expected, got dtype {values.dtype.name}")
        return [int(v) for v in np.asarray(values).reshape(-1)]
    try:
        return [int(t) for t in data.decode("ascii").replace(",", " ").split()]
    except (UnicodeDecodeError, ValueError) as exc:
        raise ValueError(f"{FLAGS['indices']}: integers separated by spaces, commas or new lines expected "
                         f"({exc})") from None


def target_spec(args: argparse.Namespace) -> dict[str, Any] | None:
    """The request's target (DetectRequest.target JSON) the flags give, None without one."""
    if getattr(args, "target_mask", None):
        return {"mask": base64.b64encode(_read(args.target_mask, FLAGS["mask"])).decode("ascii")}
    if getattr(args, "target_box", None):
        b = [float(v) for v in args.target_box]
        return {"box": {"centre": b[:3], "quat_xyzw": b[3:7], "half_extents": b[7:]}}
    if getattr(args, "target_object", None) is not None:
        return {"object": int(args.target_object)}
    if getattr(args, "target_indices", None):
        return {"indices": _indices(args.target_indices)}
    return None


def cli_target(spec: dict[str, Any] | None, given: CloudInput) -> Target | None:
    """The detector's target of spec (target_spec) on one input (its rows as read, mapped onto those kept);
    ValueError naming the flag and the field when it does not fit the cloud."""
    if spec is None:
        return None
    from graspd.server.problems import CALLER_ERRORS, Problem
    from graspd.server.requests import parse_model
    from graspd.server.services.mapping import detection_target
    from graspd.server.wire.detect import TargetSpec

    flag = FLAGS[next(iter(spec))]
    try:
        parsed = parse_model(TargetSpec, spec)
        received = given.received or len(given.cloud)
        if given.kept is None and received != len(given.cloud):
            raise ValueError(f"{flag}: the rows of this input are not known (use --target-box or --target-object)")
        return detection_target(parsed, given)
    except Problem as exc:
        raise ValueError(f"{flag}: {exc.field or 'target'}: {exc.message}") from None
    except CALLER_ERRORS as exc:  # a value the target's own checks refuse (graspd.server.problems)
        raise ValueError(f"{flag}: {exc.field}: {exc.message}") from None
