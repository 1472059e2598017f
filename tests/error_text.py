"""What an error body must never hold: a Python object's repr, a traceback, or a directory of the machine that
serves (or built) the service.  tests/conftest.py checks every 4xx/5xx body an httpx client receives in any
test against it, so a leak fails the test that provoked it."""

from __future__ import annotations

import re

#: Text that gives the server's inside away.
LEAKS = {
    "object repr": re.compile(r"<[\w.]+ object at 0x[0-9a-fA-F]+>|\bobject at 0x[0-9a-fA-F]{6,}"),
    "class repr": re.compile(r"<class '[\w.]+'>"),
    "traceback": re.compile(r"Traceback \(most recent call last\)|File \"[^\"]+\", line \d+"),
    "machine path": re.compile(r"(?<![\w.~/:])/(?:tmp|work|home|root|usr|opt|var|etc|srv|mnt)/[\w.+\-@%/]+"),
}


def leaks(text: str) -> list[str]:
    """The kinds of LEAKS found in text, each with the text that matched."""
    return [f"{kind}: {m.group(0)[:80]!r}" for kind, rx in LEAKS.items() for m in [rx.search(text)] if m]
