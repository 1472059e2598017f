"""The core's one error for a wrong value a caller gave: FieldError names the field (a dotted path such as
"cloud.points" or "hand.finger_width") and says why.  Every layer's refusals derive from it (CloudError,
StoreError, TemplateError, MeshError, ...); the server's edge turns it into a 4xx naming the field, the CLI into
a message and exit status 2.  It mirrors graspd_client's WireError without depending on the client package."""

from __future__ import annotations


class FieldError(ValueError):
    """A value is malformed or out of range; `field` is its dotted path ("" when no one field is to blame)."""

    def __init__(self, field: str, message: str) -> None:
        self.field = field
        self.message = message
        super().__init__(f"{field}: {message}" if field else message)
