"""The outcome store: every reported grasp outcome (POST /feedback) with its pose, width and, when available,
its template and GPD grasp image, shared by both detectors (a template grasp's outcome also carries its
library entry and template; a GPD grasp's has neither).  Training reads it to fine-tune the classifier:

    with OutcomeStore(url) as store:
        for row in store.iter_outcomes(with_images_only=True): ...

It lives in the same database as the template library (graspd.store.database), so both see one store.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np
import sqlalchemy as sa
from numpy.typing import NDArray
from sqlalchemy.engine import Connection

from graspd.core.types import F64
from graspd.store.database import Database, StoreError, outcomes


@dataclass(frozen=True)
class Feedback:
    """What one outcome report did: the stored outcome id, the library entry it concerned and whether
    the candidate template joined that entry's failure set."""

    outcome_id: int
    grasp_id: str
    entry_id: int | None
    success: bool
    failure_added: bool
    image_stored: bool

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        return dict(self.__dict__)


def check_success(success: object) -> bool:
    """success as a bool; StoreError naming success unless it is true or false."""
    if not isinstance(success, (bool, np.bool_)):
        raise StoreError("success", f"must be true or false, got {success!r}")
    return bool(success)


def _square(blob: bytes, dtype: type[np.generic]) -> NDArray[Any] | None:
    """A stored template (n*n values) as n x n; None for none (a GPD grasp's)."""
    if not blob:
        return None
    flat = np.frombuffer(blob, dtype)
    n = math.isqrt(len(flat))
    return flat.reshape(n, n)


class OutcomeStore:
    """The outcomes table of a Database (or of the store at an SQLAlchemy URL, created and migrated on open)."""

    def __init__(self, db: Database | str) -> None:
        self.db = db if isinstance(db, Database) else Database(db)

    def close(self) -> None:
        self.db.close()

    def __enter__(self) -> OutcomeStore:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def insert(self, conn: Connection, grasp_id: str, success: bool, pose: F64, width: float,
               image: NDArray[np.uint8] | None, representation: str | None, entry_id: int | None = None,
               heights: NDArray[np.float32] | None = None, types: NDArray[np.uint8] | None = None) -> int:
        """Store one outcome in the transaction conn (the template library adds its failure set in the same
        one); its id.  heights/types: the grasp's template (none for a GPD grasp)."""
        res = conn.execute(outcomes.insert().values(
            grasp_id=grasp_id, success=bool(success), entry_id=entry_id, created_at=time.time(),
            heights=np.asarray(np.zeros(0) if heights is None else heights, np.float32).tobytes(),
            types=np.asarray(np.zeros(0) if types is None else types, np.uint8).tobytes(),
            pose=np.asarray(pose, np.float64).tobytes(), width=float(width),
            image=None if image is None else np.ascontiguousarray(image, np.uint8).tobytes(),
            image_shape=None if image is None else json.dumps(list(image.shape)),
            representation=representation if image is not None else None))
        pk = res.inserted_primary_key
        assert pk is not None
        return int(pk[0])

    def add_outcome(self, grasp_id: str, success: bool, pose: F64, width: float,
                    image: NDArray[np.uint8] | None, representation: str | None = "15") -> Feedback:
        """Store the outcome of a grasp no library entry produced (a GPD grasp): its pose (4x4, cloud frame),
        width (m) and grasp image; it has no template, so no failure set changes."""
        ok = check_success(success)
        with self.db.begin() as conn:
            oid = self.insert(conn, grasp_id, ok, np.asarray(pose, np.float64).reshape(4, 4), width, image,
                              representation)
        return Feedback(outcome_id=oid, grasp_id=grasp_id, entry_id=None, success=ok, failure_added=False,
                        image_stored=image is not None)

    def iter_outcomes(self, with_images_only: bool = False) -> Iterator[dict[str, Any]]:
        """Every stored outcome (oldest first): grasp_id, success, entry_id, pose (4,4), width, template
        heights/types (n,n; None for a GPD grasp), image (uint8 C x 60 x 60 or None), representation; for GPD
        fine-tuning."""
        q = sa.select(outcomes).order_by(outcomes.c.id)
        if with_images_only:
            q = q.where(outcomes.c.image.is_not(None))
        with self.db.connect() as conn:
            for r in conn.execute(q):
                img = None
                if r.image is not None:
                    img = np.frombuffer(r.image, np.uint8).reshape(json.loads(r.image_shape))
                yield {"grasp_id": r.grasp_id, "success": bool(r.success), "entry_id": r.entry_id,
                       "pose": np.frombuffer(r.pose, np.float64).reshape(4, 4), "width": float(r.width),
                       "heights": _square(r.heights, np.float32), "types": _square(r.types, np.uint8),
                       "image": img, "representation": r.representation}

    @staticmethod
    def counts(conn: Connection) -> dict[str, Any]:
        """In the read connection conn: num_outcomes, num_successes, num_images, and per_entry
        {entry id: (outcomes, successes)} of the template grasps."""
        success = sa.cast(outcomes.c.success, sa.Integer)
        per_entry = {int(e): (int(n), int(s or 0)) for e, n, s in conn.execute(
            sa.select(outcomes.c.entry_id, sa.func.count(), sa.func.sum(success))
            .group_by(outcomes.c.entry_id)).all() if e is not None}
        n_out, n_ok = conn.execute(sa.select(sa.func.count(), sa.func.sum(success))).one()
        n_img = conn.execute(sa.select(sa.func.count()).where(outcomes.c.image.is_not(None))).scalar_one()
        return {"num_outcomes": int(n_out), "num_successes": int(n_ok or 0), "num_images": int(n_img),
                "per_entry": per_entry}
