"""The error answers are built in one place (graspd.server.problems: the 500, 504, 503, 413 and 422 answers and
error_body, the one body every transport sends): no transport module (the HTTP routes and app, Zenoh, the ROS 2
node) words an internal error, calls Problem.body() or writes an error body's dict itself."""

from __future__ import annotations

import ast
from pathlib import Path

import graspd.server

SERVER = Path(graspd.server.__file__).parent
TRANSPORTS = sorted([SERVER / "app.py", *(SERVER / "api").glob("*.py"), *(SERVER / "zenoh").glob("*.py"),
                     *(SERVER / "ros2").glob("*.py")])


def error_bodies_built(source: str) -> list[str]:
    """What in source builds an error answer itself: an "internal error" wording, a .body() call (Problem's own
    body), a dict literal with the body's "error" and "detail" keys; each as "line: what"."""
    found: list[str] = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Constant) and isinstance(node.value, str) and "internal error" in node.value:
            found.append(f"{node.lineno}: the words 'internal error'")
        elif isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr == "body":
            found.append(f"{node.lineno}: .body()")
        elif isinstance(node, ast.Dict):
            keys = {k.value for k in node.keys if isinstance(k, ast.Constant)}
            if {"error", "detail"} <= keys:
                found.append(f"{node.lineno}: an error body's dict")
    return found


def test_no_transport_module_builds_an_error_body() -> None:
    assert len(TRANSPORTS) >= 15 and SERVER / "zenoh" / "gate.py" in TRANSPORTS
    built = {path.relative_to(SERVER).as_posix(): found for path in TRANSPORTS
             if (found := error_bodies_built(path.read_text()))}
    assert built == {}


def test_the_scan_sees_a_body_built_by_hand() -> None:
    hand_made = ('body = {"error": str(exc), "field": None, "detail": []}\n'
                 'other = exc.body()\n'
                 'text = f"internal error (request {rid})"\n')
    assert [line.split(":")[0] for line in error_bodies_built(hand_made)] == ["1", "2", "3"]
    assert error_bodies_built('log.info("refused", extra={"field": f, "error": message})\n') == []
