"""Each ROS interface file (.msg, .srv) is kept once: the colcon package in ros2/ links to the field lists the
service ships as package data (so the wheel and the colcon build read the same text), and no two files in the
repository hold the same interface."""

from __future__ import annotations

import fnmatch
import tomllib
from collections import Counter
from pathlib import Path

REPO = Path(__file__).resolve().parents[3]
PACKAGE = REPO / "ros2"
SERVICE = REPO / "service" / "graspd"


def interface_files() -> list[Path]:
    """Every .msg and .srv file of the service, the client, the lab and the colcon package, links included."""
    roots = [REPO / "service", REPO / "client", REPO / "lab", PACKAGE]
    return sorted(p for r in roots for ext in ("*.msg", "*.srv") for p in r.rglob(ext))


def test_the_colcon_package_links_to_the_service_package_data() -> None:
    linked = [*PACKAGE.glob("msg/*.msg"), *PACKAGE.glob("srv/*.srv")]
    assert {p.name for p in linked} == {"GraspConfig.msg", "GraspConfigList.msg", "CloudSources.msg",
                                        "CloudIndexed.msg", "CloudSamples.msg", "DetectGrasps.srv"}
    globs = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]["package-data"]["graspd"]
    for path in linked:
        assert path.is_symlink(), path  # a relative link inside the repository, committed in git
        target = path.resolve()
        assert target.is_file() and target.is_relative_to(SERVICE), (path, target)
        shipped = target.relative_to(SERVICE).as_posix()
        assert any(fnmatch.fnmatch(shipped, g) for g in globs), shipped  # the wheel carries it


def test_no_interface_is_held_twice() -> None:
    files = [p for p in interface_files() if not p.is_symlink()]
    assert len(files) >= 18  # the service's gpd_ros, moveit_msgs, vision_msgs... field lists
    twice = [k for k, n in Counter((p.name, p.read_bytes()) for p in files).items() if n > 1]
    assert twice == []
    # the check sees a copy: the same name and text in two places
    assert Counter([("A.msg", b"int32 x"), ("A.msg", b"int32 x")])[("A.msg", b"int32 x")] == 2
