"""The error every held-out guard of the object catalogue raises (random_urdfs 900-999, the held-out household
models): one type, so a caller catches one thing whichever object set refused."""

from __future__ import annotations


class HeldOutObjectError(PermissionError):
    """A held-out test object was requested for training or validation."""
