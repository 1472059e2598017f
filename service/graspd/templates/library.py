"""The grasp library (Herzog et al. 2012): demonstrated templates, their failure sets F_l, the detections
feedback refers to, and the outcomes reported (graspd.store.outcomes), in one database (graspd.store.database).

A new library records the hand and template geometry it is made for; the snapshot of entries and
failures used for matching is re-read only when any writer changed them.
"""

from __future__ import annotations

import json
import time
import uuid
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np
import sqlalchemy as sa
from numpy.typing import NDArray
from sqlalchemy.engine import Connection, Engine

from graspd.core.cloud import ViewpointCloud
from graspd.core.hand import HandGeometry
from graspd.core.types import F32, F64
from graspd.gpd.images import REPRESENTATIONS
from graspd.store.database import (
    SCHEMA_VERSION,
    Database,
    StoreError,
    detections,
    entries,
    failures,
    from_npz,
    meta,
    to_npz,
)
from graspd.store.outcomes import Feedback, OutcomeStore, check_success
from graspd.templates.collision import closing_widths
from graspd.templates.demonstration import cloud_from_arrays, demonstration_template, grasp_image
from graspd.templates.geometry import TemplateError, TemplateGeometry, prepare_scene
from graspd.templates.matching import entry_gammas

U8 = NDArray[np.uint8]

DEFAULT_URL = "sqlite:///graspd-templates.db"


def _check_success(success: object) -> None:
    """TemplateError naming success unless it is true or false."""
    try:
        check_success(success)
    except StoreError as exc:
        raise TemplateError(exc.field, exc.message) from None


class UnknownGrasp(TemplateError):
    """A well-formed grasp id that names no stored detection or grasp (the service answers 404)."""


@dataclass(frozen=True)
class LibrarySnapshot:
    """The library as arrays for matching: entries (L) and failures (F, owner = entry row)."""

    entry_ids: NDArray[np.int64]
    heights: F32
    types: U8
    grasps: F64  # (L,4,4) hand pose relative to the template frame
    widths: F64
    f_heights: F32
    f_types: U8
    f_owner: NDArray[np.int64]
    gamma: F64
    key: tuple[int, ...]

    def __len__(self) -> int:
        return len(self.entry_ids)


class TemplateLibrary:
    """The grasp library at an SQLAlchemy URL (created and migrated on open).

    A new library records the hand and template geometry it is made for; opening an existing one with a
    different hand raises TemplateError naming "hand".
    """

    def __init__(self, url: str = DEFAULT_URL, hand: HandGeometry | None = None,
                 geometry: TemplateGeometry | None = None) -> None:
        self.url = url
        try:
            self.db = Database(url)
        except StoreError as exc:
            raise TemplateError(exc.field, exc.message) from None
        self.outcomes = OutcomeStore(self.db)
        self.hand, self.geometry = self._settle_meta(hand, geometry)
        self._snapshot: LibrarySnapshot | None = None

    @property
    def engine(self) -> Engine:
        """The SQLAlchemy engine of the library's database."""
        return self.db.engine

    def _settle_meta(self, hand: HandGeometry | None, geometry: TemplateGeometry | None
                     ) -> tuple[HandGeometry, TemplateGeometry]:
        with self.db.begin() as conn:
            rows = dict(conn.execute(sa.select(meta.c.key, meta.c.value)).all())
            if "hand" not in rows:
                h = hand or HandGeometry()
                g = geometry or TemplateGeometry.for_hand(h)
                conn.execute(meta.insert(), [{"key": "hand", "value": json.dumps(h.to_dict())},
                                             {"key": "geometry", "value": json.dumps(g.__dict__)}])
                return h, g
        h0 = HandGeometry(**json.loads(rows["hand"]))
        g0 = TemplateGeometry(**json.loads(rows["geometry"]))
        if hand is not None and hand != h0:
            raise TemplateError("hand", f"this library was made for {h0.to_dict()}, not {hand.to_dict()}")
        if geometry is not None and geometry != g0:
            raise TemplateError("template", f"this library uses {g0.__dict__}, not {geometry.__dict__}")
        return h0, g0

    def close(self) -> None:
        self.db.close()

    def __enter__(self) -> TemplateLibrary:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- writing --------------------------------------------------------------------------------------

    def add_demonstration(self, cloud: Any, hand_pose: Any, label: str | None = None,
                          workspace: tuple[float, ...] | None = None) -> int:
        """Add a library entry from a demonstration: cloud (ViewpointCloud: table + object) and the
        demonstrated hand pose (4x4, rotation columns [approach, binormal, axis], translation = hand base
        centre, cloud frame).  Returns the entry id.  TemplateError / CloudError name the bad field."""
        if not isinstance(cloud, ViewpointCloud):
            raise TemplateError("cloud", "must be a graspd.core.cloud.ViewpointCloud")
        if label is not None and (not isinstance(label, str) or len(label) > 200):
            raise TemplateError("label", "must be a string of at most 200 characters")
        scene = prepare_scene(cloud, self.geometry, workspace)
        heights, types, frame = demonstration_template(scene, hand_pose, self.hand)
        pose = np.asarray(hand_pose, np.float64)
        width = float(closing_widths(scene, pose[None, :3, 3], pose[None, :3, :3], self.hand, np.zeros(1))[0])
        return self.insert_entry(heights, types, frame, np.linalg.inv(frame) @ pose, width, label)

    def add_feedback(self, grasp_id: str, success: bool, cloud: Any = None,
                     image: NDArray[np.uint8] | None = None, representation: str = "15") -> Feedback:
        """Report the outcome of an executed grasp by the id template detection returned.  A failure adds the
        candidate's template to the failure set F_l of the library entry it came from (once per grasp id);
        every outcome is stored with the grasp, its template and its GPD grasp image: the image given, or
        one encoded (representation) from the cloud given or kept with the detection."""
        _check_success(success)
        grasp, kept = self.detection_grasp(grasp_id)
        if image is not None:
            image = np.asarray(image)
            if image.dtype != np.uint8 or image.ndim != 3:
                raise TemplateError("image", f"must be uint8 (C, H, W), got {image.dtype} {image.shape}")
        elif cloud is not None or kept is not None:
            if representation not in REPRESENTATIONS:
                raise TemplateError("representation", f"must be one of {sorted(REPRESENTATIONS)}, "
                                                      f"got {representation!r}")
            src = cloud if cloud is not None else cloud_from_arrays(kept or {})
            image = grasp_image(src, grasp["pose"], grasp["width"], self.hand, representation)
        return self.store_outcome(grasp_id, bool(success), grasp, image, representation)

    def insert_entry(self, heights: F32, types: U8, frame: F64, grasp: F64, width: float,
                     label: str | None = None) -> int:
        """Store one library entry (template, its frame and the hand pose relative to it); its id."""
        self._check_template(heights, types, "template")
        with self.db.begin() as conn:
            res = conn.execute(entries.insert().values(
                created_at=time.time(), label=label, heights=np.asarray(heights, np.float32).tobytes(),
                types=np.asarray(types, np.uint8).tobytes(), frame=np.asarray(frame, np.float64).tobytes(),
                grasp=np.asarray(grasp, np.float64).tobytes(), width=float(width)))
            pk = res.inserted_primary_key
            assert pk is not None
            return int(pk[0])

    def record_detection(self, heights: F32, types: U8, entry_ids: NDArray[np.int64], poses: F64,
                         widths: F64, mismatch: F64, cloud: dict[str, NDArray[Any]] | None = None) -> str:
        """Store what a detection returned (one row); the detection id.  Grasp k is '<id>.<k>'."""
        det_id = uuid.uuid4().hex
        payload = to_npz(heights=np.asarray(heights, np.float32), types=np.asarray(types, np.uint8),
                         entry_ids=np.asarray(entry_ids, np.int64), poses=np.asarray(poses, np.float64),
                         widths=np.asarray(widths, np.float64), mismatch=np.asarray(mismatch, np.float64))
        with self.db.begin() as conn:
            conn.execute(detections.insert().values(id=det_id, created_at=time.time(), payload=payload,
                                                    cloud=None if cloud is None else to_npz(False, **cloud)))
        return det_id

    def prune_detections(self, keep: int) -> int:
        """Delete all but the `keep` newest recorded detections (their grasp ids then raise UnknownGrasp); how
        many were deleted.  Entries, failure sets and outcomes stay."""
        with self.db.begin() as conn:
            if keep <= 0:
                return int(conn.execute(detections.delete()).rowcount)
            cutoff = conn.execute(sa.select(detections.c.created_at).order_by(detections.c.created_at.desc())
                                  .offset(keep - 1).limit(1)).scalar()
            if cutoff is None:
                return 0
            return int(conn.execute(detections.delete().where(detections.c.created_at < cutoff)).rowcount)

    def detection_grasp(self, grasp_id: str) -> tuple[dict[str, Any], dict[str, NDArray[Any]] | None]:
        """The stored template, entry, pose and width of a returned grasp, and the detection's cloud arrays
        (None if not kept).  TemplateError naming grasp_id if unknown."""
        det_id, k = parse_grasp_id(grasp_id)
        with self.db.connect() as conn:
            row = conn.execute(sa.select(detections.c.payload, detections.c.cloud)
                               .where(detections.c.id == det_id)).first()
        if row is None:
            raise UnknownGrasp("grasp_id", f"{grasp_id!r}: no such detection (ids come from template detection; "
                                           "old detections may have been pruned)")
        p = from_npz(row[0])
        if k >= len(p["entry_ids"]):
            raise UnknownGrasp("grasp_id", f"{grasp_id!r}: that detection returned {len(p['entry_ids'])} grasps")
        grasp = {"heights": p["heights"][k], "types": p["types"][k], "entry_id": int(p["entry_ids"][k]),
                 "pose": p["poses"][k], "width": float(p["widths"][k]), "mismatch": float(p["mismatch"][k])}
        return grasp, None if row[1] is None else from_npz(row[1])

    def store_outcome(self, grasp_id: str, success: bool, grasp: dict[str, Any],
                      image: NDArray[np.uint8] | None, representation: str | None) -> Feedback:
        """Store an outcome; on failure add the candidate template to F_l of its entry (once per grasp id)."""
        entry_id = grasp["entry_id"]
        with self.db.begin() as conn:
            oid = self.outcomes.insert(conn, grasp_id, success, grasp["pose"], grasp["width"], image,
                                       representation, entry_id, grasp["heights"], grasp["types"])
            added = False
            if not success:
                exists = conn.execute(sa.select(entries.c.id).where(entries.c.id == entry_id)).first()
                dup = conn.execute(sa.select(failures.c.id).where(failures.c.grasp_id == grasp_id)).first()
                if exists is not None and dup is None:
                    conn.execute(failures.insert().values(
                        entry_id=entry_id, grasp_id=grasp_id, created_at=time.time(),
                        heights=np.asarray(grasp["heights"], np.float32).tobytes(),
                        types=np.asarray(grasp["types"], np.uint8).tobytes()))
                    added = True
        return Feedback(outcome_id=oid, grasp_id=grasp_id, entry_id=entry_id, success=bool(success),
                        failure_added=added, image_stored=image is not None)

    def add_outcome(self, grasp_id: str, success: bool, pose: F64, width: float,
                    image: NDArray[np.uint8] | None, representation: str | None = "15") -> Feedback:
        """Store the outcome of a grasp no library entry produced (a GPD grasp; graspd.store.outcomes.OutcomeStore):
        its pose (4x4, cloud frame), width (m) and grasp image; no failure set changes."""
        _check_success(success)
        return self.outcomes.add_outcome(grasp_id, bool(success), pose, width, image, representation)

    # -- reading --------------------------------------------------------------------------------------

    def _key(self, conn: Connection) -> tuple[int, ...]:
        row = conn.execute(sa.select(sa.func.count(entries.c.id), sa.func.max(entries.c.id))).one()
        frow = conn.execute(sa.select(sa.func.count(failures.c.id), sa.func.max(failures.c.id))).one()
        return (int(row[0]), int(row[1] or 0), int(frow[0]), int(frow[1] or 0))

    def snapshot(self) -> LibrarySnapshot:
        """The library as arrays, re-read only when entries or failures changed (any writer)."""
        t = self.geometry.num_tiles
        with self.db.connect() as conn:
            key = self._key(conn)
            if self._snapshot is not None and self._snapshot.key == key:
                return self._snapshot
            rows = conn.execute(sa.select(entries.c.id, entries.c.heights, entries.c.types, entries.c.grasp,
                                          entries.c.width).order_by(entries.c.id)).all()
            frows = conn.execute(sa.select(failures.c.entry_id, failures.c.heights, failures.c.types)
                                 .order_by(failures.c.id)).all()
        ids = np.array([r[0] for r in rows], np.int64)
        row_of = {int(e): i for i, e in enumerate(ids)}
        frows = [r for r in frows if int(r[0]) in row_of]
        snap_h = np.array([np.frombuffer(r[1], np.float32) for r in rows], np.float32).reshape(-1, t)
        snap_t = np.array([np.frombuffer(r[2], np.uint8) for r in rows], np.uint8).reshape(-1, t)
        f_h = np.array([np.frombuffer(r[1], np.float32) for r in frows], np.float32).reshape(-1, t)
        f_t = np.array([np.frombuffer(r[2], np.uint8) for r in frows], np.uint8).reshape(-1, t)
        f_owner = np.array([row_of[int(r[0])] for r in frows], np.int64)
        snap = LibrarySnapshot(
            entry_ids=ids, heights=snap_h, types=snap_t,
            grasps=np.array([np.frombuffer(r[3], np.float64).reshape(4, 4) for r in rows]).reshape(-1, 4, 4),
            widths=np.array([r[4] for r in rows], np.float64), f_heights=f_h, f_types=f_t, f_owner=f_owner,
            gamma=entry_gammas(snap_h, snap_t, f_h, f_t, f_owner), key=key)
        self._snapshot = snap
        return snap

    def entry(self, entry_id: int) -> dict[str, Any]:
        """One entry: id, label, created_at, template heights/types (n x n), frame, grasp, width, failures."""
        n = self.geometry.n
        with self.db.connect() as conn:
            r = conn.execute(sa.select(entries).where(entries.c.id == entry_id)).first()
            if r is None:
                raise TemplateError("entry_id", f"{entry_id}: no such library entry")
            nf = conn.execute(sa.select(sa.func.count()).where(failures.c.entry_id == entry_id)).scalar_one()
        return {"id": int(r.id), "label": r.label, "created_at": float(r.created_at),
                "heights": np.frombuffer(r.heights, np.float32).reshape(n, n),
                "types": np.frombuffer(r.types, np.uint8).reshape(n, n),
                "frame": np.frombuffer(r.frame, np.float64).reshape(4, 4),
                "grasp": np.frombuffer(r.grasp, np.float64).reshape(4, 4),
                "width": float(r.width), "num_failures": int(nf)}

    def summary(self) -> dict[str, Any]:
        """JSON-ready: counts, the hand and template geometry, and one line per entry (id, label,
        created_at, failures, outcomes, successes)."""
        with self.db.connect() as conn:
            erows = conn.execute(sa.select(entries.c.id, entries.c.label, entries.c.created_at)
                                 .order_by(entries.c.id)).all()
            fcount: dict[int, int] = {int(e): int(c) for e, c in conn.execute(
                sa.select(failures.c.entry_id, sa.func.count()).group_by(failures.c.entry_id)).all()}
            counts = self.outcomes.counts(conn)
            n_det = conn.execute(sa.select(sa.func.count()).select_from(detections)).scalar_one()
        lines = [{"id": int(e), "label": lab, "created_at": float(ts), "failures": int(fcount.get(e, 0)),
                  "outcomes": counts["per_entry"].get(int(e), (0, 0))[0],
                  "successes": counts["per_entry"].get(int(e), (0, 0))[1]}
                 for e, lab, ts in erows]
        return {"num_entries": len(lines), "num_failures": int(sum(fcount.values())),
                "num_outcomes": counts["num_outcomes"], "num_successes": counts["num_successes"],
                "num_images": counts["num_images"],
                "num_detections": int(n_det), "schema_version": SCHEMA_VERSION,
                "hand": self.hand.to_dict(), "template": dict(self.geometry.__dict__), "entries": lines}

    def iter_outcomes(self, with_images_only: bool = False) -> Iterator[dict[str, Any]]:
        """Every stored outcome, oldest first (graspd.store.outcomes.OutcomeStore.iter_outcomes)."""
        return self.outcomes.iter_outcomes(with_images_only)

    def _check_template(self, heights: NDArray[Any], types: NDArray[Any], field: str) -> None:
        t = self.geometry.num_tiles
        if np.asarray(heights).size != t or np.asarray(types).size != t:
            raise TemplateError(field, f"expected {t} tiles (n = {self.geometry.n})")


def parse_grasp_id(grasp_id: object) -> tuple[str, int]:
    """'<detection id>.<index>' -> (detection id, index); TemplateError naming grasp_id otherwise."""
    if not isinstance(grasp_id, str) or grasp_id.count(".") != 1:
        raise TemplateError("grasp_id", f"must look like '<detection id>.<index>', got {grasp_id!r}")
    det, _, k = grasp_id.partition(".")
    if not det or not k.isdigit() or len(det) > 32:
        raise TemplateError("grasp_id", f"must look like '<detection id>.<index>', got {grasp_id!r}")
    return det, int(k)
