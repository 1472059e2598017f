"""The persistent grasp library and feedback store (SQLAlchemy Core; SQLite by default, any URL by setting).

Tables: entries (demonstrated templates with their gripper pose relative to the template frame),
failures (the sets F_l: candidate templates whose grasp from entry l failed), detections (what each
template detection returned, so feedback can refer to a grasp by id), outcomes (every reported
outcome with its template, pose and, when available, its GPD grasp image, for fine-tuning later),
meta (the template geometry and hand the library was made for), schema_version.

Schema changes are ordered migration steps (MIGRATIONS); opening a library applies the missing ones in
one write transaction, so concurrent openers agree.  SQLite runs in WAL mode with every transaction
BEGIN IMMEDIATE and a busy timeout, so concurrent writers (threads or processes) queue instead of
losing rows.
"""

from __future__ import annotations

import io
import json
import re
import threading
import time
import uuid
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

import numpy as np
import sqlalchemy as sa
from numpy.typing import NDArray
from sqlalchemy.engine import Connection, Engine

from ..hand import HandGeometry
from .geometry import TemplateError, TemplateGeometry

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]
U8 = NDArray[np.uint8]

DEFAULT_URL = "sqlite:///graspd-templates.db"

metadata = sa.MetaData()
schema_version = sa.Table("schema_version", metadata, sa.Column("version", sa.Integer, nullable=False))
meta = sa.Table("meta", metadata, sa.Column("key", sa.String(64), primary_key=True),
                sa.Column("value", sa.Text, nullable=False))
entries = sa.Table(
    "entries", metadata,
    sa.Column("id", sa.Integer, primary_key=True, autoincrement=True),
    sa.Column("created_at", sa.Float, nullable=False),
    sa.Column("label", sa.String(200)),
    sa.Column("heights", sa.LargeBinary, nullable=False),  # float32 (n*n,) depth below the template plane (m)
    sa.Column("types", sa.LargeBinary, nullable=False),  # uint8 (n*n,) region types
    sa.Column("frame", sa.LargeBinary, nullable=False),  # float64 4x4 template frame in the demo cloud's frame
    sa.Column("grasp", sa.LargeBinary, nullable=False),  # float64 4x4 hand pose relative to the template frame
    sa.Column("width", sa.Float, nullable=False),
)
failures = sa.Table(
    "failures", metadata,
    sa.Column("id", sa.Integer, primary_key=True, autoincrement=True),
    sa.Column("entry_id", sa.Integer, sa.ForeignKey("entries.id", ondelete="CASCADE"), nullable=False),
    sa.Column("grasp_id", sa.String(64), unique=True),
    sa.Column("created_at", sa.Float, nullable=False),
    sa.Column("heights", sa.LargeBinary, nullable=False),
    sa.Column("types", sa.LargeBinary, nullable=False),
)
detections = sa.Table(
    "detections", metadata,
    sa.Column("id", sa.String(32), primary_key=True),
    sa.Column("created_at", sa.Float, nullable=False),
    sa.Column("payload", sa.LargeBinary, nullable=False),  # npz: heights, types, entry_ids, poses, mismatch
    sa.Column("cloud", sa.LargeBinary),  # npz: points, viewpoints, camera_source (optional)
)


def _outcome_columns_v1() -> list[sa.Column[Any]]:
    """The outcome columns of schema v1 (fresh objects, one set per table)."""
    return [
        sa.Column("id", sa.Integer, primary_key=True, autoincrement=True),
        sa.Column("grasp_id", sa.String(64), nullable=False),
        sa.Column("success", sa.Boolean, nullable=False),
        sa.Column("entry_id", sa.Integer),
        sa.Column("created_at", sa.Float, nullable=False),
        sa.Column("heights", sa.LargeBinary, nullable=False),
        sa.Column("types", sa.LargeBinary, nullable=False),
        sa.Column("pose", sa.LargeBinary, nullable=False),  # float64 4x4 grasp pose (DESIGN.md convention)
        sa.Column("width", sa.Float, nullable=False),
    ]


outcomes = sa.Table(
    "outcomes", metadata, *_outcome_columns_v1(),
    sa.Column("image", sa.LargeBinary),  # v2: uint8 grasp image, shape in image_shape (JSON list)
    sa.Column("image_shape", sa.String(64)),
    sa.Column("representation", sa.String(16)),
)


def _v1(conn: Connection) -> None:
    """Library, failures, detections and outcomes (without images).  The tables as they were in v1:
    when a later step changes one of them, freeze its v1 columns here."""
    md = sa.MetaData()
    for table in (meta, entries, failures, detections):
        table.to_metadata(md)
    sa.Table("outcomes", md, *_outcome_columns_v1())
    md.create_all(conn)


def _v2(conn: Connection) -> None:
    """Outcomes keep the GPD grasp image (uint8 C x 60 x 60 and its representation); lookup indexes."""
    conn.execute(sa.text("ALTER TABLE outcomes ADD COLUMN image BYTEA" if conn.dialect.name == "postgresql"
                         else "ALTER TABLE outcomes ADD COLUMN image BLOB"))
    conn.execute(sa.text("ALTER TABLE outcomes ADD COLUMN image_shape VARCHAR(64)"))
    conn.execute(sa.text("ALTER TABLE outcomes ADD COLUMN representation VARCHAR(16)"))
    conn.execute(sa.text("CREATE INDEX IF NOT EXISTS ix_failures_entry ON failures (entry_id)"))
    conn.execute(sa.text("CREATE INDEX IF NOT EXISTS ix_outcomes_grasp ON outcomes (grasp_id)"))


#: Ordered schema steps; step i brings the schema from version i to i + 1.  Append, never edit.
MIGRATIONS: list[Callable[[Connection], None]] = [_v1, _v2]
SCHEMA_VERSION = len(MIGRATIONS)


#: user:password@ in any URL-like text (the password is masked); DSN-style password=... (libpq keywords)
_URL_CREDENTIALS = re.compile(r"(?P<head>[A-Za-z][A-Za-z0-9+.\-]*://[^:/@\s'\"]*):[^@\s'\"]*@")
_DSN_PASSWORD = re.compile(r"(?i)\b(?P<key>password|passwd|pwd)(?P<eq>\s*=\s*)"
                           r"(?:'(?:[^'\\]|\\.)*'|\"[^\"]*\"|[^\s&;,'\"]+)")
MASK = "***"


def _password_of(url: str) -> str | None:
    """The password in an SQLAlchemy URL, also from a URL that does not parse (text between 'user:' and the
    last '@')."""
    try:
        password = sa.engine.make_url(url).password
        if password:
            return str(password)
    except Exception:  # not a URL SQLAlchemy can parse: look at the text
        pass
    m = re.match(r"^[^:/]+://[^:/@]*:(.+)@[^@]*$", url.strip())
    return m.group(1) if m else None


def redact_url(url: str) -> str:
    """url with its password masked (SQLAlchemy's render_as_string(hide_password=True)), for errors and logs."""
    try:
        return str(sa.engine.make_url(url).render_as_string(hide_password=True))
    except Exception:  # unparsable: mask whatever looks like credentials
        return redact_text(url, url)


def redact_text(text: str, url: str | None = None) -> str:
    """text (an exception message, a log line) with every URL password, DSN password=..., and the password of
    url in any spelling (raw, %-encoded) masked: drivers and SQLAlchemy may quote the URL or DSN they got."""
    out = text
    password = _password_of(url) if url else None
    if password:
        from urllib.parse import quote, quote_plus, unquote

        for form in sorted({password, unquote(password), quote(password, safe=""), quote_plus(password)},
                           key=len, reverse=True):
            out = out.replace(form, MASK)
    out = _URL_CREDENTIALS.sub(lambda m: f"{m['head']}:{MASK}@", out)
    return _DSN_PASSWORD.sub(lambda m: f"{m['key']}{m['eq']}{MASK}", out)


def make_engine(url: str) -> Engine:
    """An engine for url; SQLite gets WAL, a 60 s busy timeout and BEGIN IMMEDIATE transactions.  Errors
    quote the URL with its password masked."""
    if not isinstance(url, str) or not url:
        raise TemplateError(f"library_url must be an SQLAlchemy URL string, got {url!r}")  # not a secret: empty
    try:
        parsed = sa.engine.make_url(url)
    except sa.exc.ArgumentError:
        raise TemplateError(f"library_url is not an SQLAlchemy URL: {redact_url(url)!r}") from None
    if parsed.get_backend_name() != "sqlite":
        return sa.create_engine(url, pool_pre_ping=True)
    memory = parsed.database in (None, "", ":memory:")
    engine = sa.create_engine(url, connect_args={"timeout": 60, "check_same_thread": False},
                              **({"poolclass": sa.pool.StaticPool} if memory else {}))  # one shared in-memory db

    @sa.event.listens_for(engine, "connect")
    def _connect(dbapi_conn: Any, _record: Any) -> None:
        dbapi_conn.isolation_level = None  # let the "begin" hook below own transactions
        cur = dbapi_conn.cursor()
        cur.execute("PRAGMA busy_timeout = 60000")
        if not memory:
            cur.execute("PRAGMA journal_mode = WAL")
        cur.execute("PRAGMA foreign_keys = ON")
        cur.close()

    @sa.event.listens_for(engine, "begin")
    def _begin(conn: Connection) -> None:
        conn.exec_driver_sql("BEGIN IMMEDIATE")

    return engine


def migrate(engine: Engine, target: int = SCHEMA_VERSION) -> int:
    """Apply the missing migration steps up to target in one write transaction; the resulting version."""
    for attempt in range(5):
        try:
            with engine.begin() as conn:
                schema_version.create(conn, checkfirst=True)
                if conn.dialect.name == "postgresql":
                    conn.execute(sa.text("LOCK TABLE schema_version IN EXCLUSIVE MODE"))
                row = conn.execute(sa.select(schema_version.c.version)).first()
                version = 0 if row is None else int(row[0])
                if row is None:
                    conn.execute(schema_version.insert().values(version=0))
                for step in range(version, target):
                    MIGRATIONS[step](conn)
                if target > version:
                    conn.execute(schema_version.update().values(version=target))
                return max(version, target)
        except (sa.exc.IntegrityError, sa.exc.ProgrammingError):
            if attempt == 4:  # another process created the version table at the same moment
                raise
            time.sleep(0.1 * (attempt + 1))
    raise AssertionError("unreachable")


def to_npz(compress: bool = True, **arrays: NDArray[Any]) -> bytes:
    buf = io.BytesIO()
    (np.savez_compressed if compress else np.savez)(buf, **arrays)  # type: ignore[operator, arg-type]
    return buf.getvalue()


def from_npz(blob: bytes) -> dict[str, NDArray[Any]]:
    with np.load(io.BytesIO(blob)) as z:
        return {k: z[k] for k in z.files}


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
        return dict(self.__dict__)


class TemplateLibrary:
    """The grasp library at an SQLAlchemy URL (created and migrated on open).

    A new library records the hand and template geometry it is made for; opening an existing one with a
    different hand raises TemplateError naming "hand".
    """

    def __init__(self, url: str = DEFAULT_URL, hand: HandGeometry | None = None,
                 geometry: TemplateGeometry | None = None) -> None:
        self.url = url
        self.engine = make_engine(url)
        # one shared in-memory SQLite connection: transactions from several threads must take turns
        self._lock = threading.RLock() if self.engine.pool.__class__ is sa.pool.StaticPool else None
        with self._locked():
            migrate(self.engine)
        self.hand, self.geometry = self._settle_meta(hand, geometry)
        self._snapshot: LibrarySnapshot | None = None

    def _settle_meta(self, hand: HandGeometry | None, geometry: TemplateGeometry | None
                     ) -> tuple[HandGeometry, TemplateGeometry]:
        with self._begin() as conn:
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
            raise TemplateError(f"hand: this library was made for {h0.to_dict()}, not {hand.to_dict()}")
        if geometry is not None and geometry != g0:
            raise TemplateError(f"template geometry: this library uses {g0.__dict__}, not {geometry.__dict__}")
        return h0, g0

    @contextmanager
    def _locked(self) -> Iterator[None]:
        if self._lock is None:
            yield
        else:
            with self._lock:
                yield

    @contextmanager
    def _begin(self) -> Iterator[Connection]:
        """A write transaction (committed on success)."""
        with self._locked(), self.engine.begin() as conn:
            yield conn

    @contextmanager
    def _connect(self) -> Iterator[Connection]:
        """A read-only connection."""
        with self._locked(), self.engine.connect() as conn:
            yield conn

    def close(self) -> None:
        self.engine.dispose()

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
        from ..cloud import ViewpointCloud
        from .demonstration import demonstration_template
        from .detector import closing_widths
        from .geometry import prepare_scene

        if not isinstance(cloud, ViewpointCloud):
            raise TemplateError("cloud must be a graspd.cloud.ViewpointCloud")
        if label is not None and (not isinstance(label, str) or len(label) > 200):
            raise TemplateError("label must be a string of at most 200 characters")
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
        if not isinstance(success, (bool, np.bool_)):
            raise TemplateError(f"success must be true or false, got {success!r}")
        grasp, kept = self.detection_grasp(grasp_id)
        if image is not None:
            image = np.asarray(image)
            if image.dtype != np.uint8 or image.ndim != 3:
                raise TemplateError(f"image must be uint8 (C, H, W), got {image.dtype} {image.shape}")
        elif cloud is not None or kept is not None:
            from ..images import REPRESENTATIONS
            from .demonstration import cloud_from_arrays, grasp_image

            if representation not in REPRESENTATIONS:
                raise TemplateError(f"representation must be one of {sorted(REPRESENTATIONS)}, "
                                    f"got {representation!r}")
            src = cloud if cloud is not None else cloud_from_arrays(kept or {})
            image = grasp_image(src, grasp["pose"], grasp["width"], self.hand, representation)
        return self.store_outcome(grasp_id, bool(success), grasp, image, representation)

    def insert_entry(self, heights: F32, types: U8, frame: F64, grasp: F64, width: float,
                     label: str | None = None) -> int:
        """Store one library entry (template, its frame and the hand pose relative to it); its id."""
        self._check_template(heights, types, "template")
        with self._begin() as conn:
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
        with self._begin() as conn:
            conn.execute(detections.insert().values(id=det_id, created_at=time.time(), payload=payload,
                                                    cloud=None if cloud is None else to_npz(False, **cloud)))
        return det_id

    def prune_detections(self, keep: int) -> int:
        """Delete all but the `keep` newest recorded detections (their grasp ids then raise UnknownGrasp); how
        many were deleted.  Entries, failure sets and outcomes stay."""
        with self._begin() as conn:
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
        with self._connect() as conn:
            row = conn.execute(sa.select(detections.c.payload, detections.c.cloud)
                               .where(detections.c.id == det_id)).first()
        if row is None:
            raise UnknownGrasp(f"grasp_id {grasp_id!r}: no such detection (ids come from template detection; "
                               "old detections may have been pruned)")
        p = from_npz(row[0])
        if k >= len(p["entry_ids"]):
            raise UnknownGrasp(f"grasp_id {grasp_id!r}: that detection returned {len(p['entry_ids'])} grasps")
        grasp = {"heights": p["heights"][k], "types": p["types"][k], "entry_id": int(p["entry_ids"][k]),
                 "pose": p["poses"][k], "width": float(p["widths"][k]), "mismatch": float(p["mismatch"][k])}
        return grasp, None if row[1] is None else from_npz(row[1])

    def store_outcome(self, grasp_id: str, success: bool, grasp: dict[str, Any],
                      image: NDArray[np.uint8] | None, representation: str | None) -> Feedback:
        """Store an outcome; on failure add the candidate template to F_l of its entry (once per grasp id)."""
        entry_id = grasp["entry_id"]
        with self._begin() as conn:
            res = conn.execute(outcomes.insert().values(
                grasp_id=grasp_id, success=bool(success), entry_id=entry_id, created_at=time.time(),
                heights=np.asarray(grasp["heights"], np.float32).tobytes(),
                types=np.asarray(grasp["types"], np.uint8).tobytes(),
                pose=np.asarray(grasp["pose"], np.float64).tobytes(), width=float(grasp["width"]),
                image=None if image is None else np.ascontiguousarray(image, np.uint8).tobytes(),
                image_shape=None if image is None else json.dumps(list(image.shape)),
                representation=representation if image is not None else None))
            pk = res.inserted_primary_key
            assert pk is not None
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
        return Feedback(outcome_id=int(pk[0]), grasp_id=grasp_id, entry_id=entry_id, success=bool(success),
                        failure_added=added, image_stored=image is not None)

    def add_outcome(self, grasp_id: str, success: bool, pose: F64, width: float,
                    image: NDArray[np.uint8] | None, representation: str | None = "15") -> Feedback:
        """Store the outcome of a grasp no library entry produced (a GPD grasp): its pose (4x4, cloud frame),
        width (m) and grasp image; it has no template, so no failure set changes."""
        if not isinstance(success, (bool, np.bool_)):
            raise TemplateError(f"success must be true or false, got {success!r}")
        grasp = {"heights": np.zeros(0, np.float32), "types": np.zeros(0, np.uint8), "entry_id": None,
                 "pose": np.asarray(pose, np.float64).reshape(4, 4), "width": float(width)}
        return self.store_outcome(grasp_id, bool(success), grasp, image, representation)

    def remove_entry(self, entry_id: int) -> bool:
        """Delete a library entry and its failure set; whether it existed."""
        with self._begin() as conn:
            conn.execute(failures.delete().where(failures.c.entry_id == entry_id))
            return bool(conn.execute(entries.delete().where(entries.c.id == entry_id)).rowcount)

    # -- reading --------------------------------------------------------------------------------------

    def _key(self, conn: Connection) -> tuple[int, ...]:
        row = conn.execute(sa.select(sa.func.count(entries.c.id), sa.func.max(entries.c.id))).one()
        frow = conn.execute(sa.select(sa.func.count(failures.c.id), sa.func.max(failures.c.id))).one()
        return (int(row[0]), int(row[1] or 0), int(frow[0]), int(frow[1] or 0))

    def snapshot(self) -> LibrarySnapshot:
        """The library as arrays, re-read only when entries or failures changed (any writer)."""
        from .matching import entry_gammas

        t = self.geometry.num_tiles
        with self._connect() as conn:
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
        with self._connect() as conn:
            r = conn.execute(sa.select(entries).where(entries.c.id == entry_id)).first()
            if r is None:
                raise TemplateError(f"entry_id {entry_id}: no such library entry")
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
        with self._connect() as conn:
            erows = conn.execute(sa.select(entries.c.id, entries.c.label, entries.c.created_at)
                                 .order_by(entries.c.id)).all()
            fcount: dict[int, int] = {int(e): int(c) for e, c in conn.execute(
                sa.select(failures.c.entry_id, sa.func.count()).group_by(failures.c.entry_id)).all()}
            ocount = {int(e): (int(n), int(s or 0)) for e, n, s in conn.execute(
                sa.select(outcomes.c.entry_id, sa.func.count(), sa.func.sum(sa.cast(outcomes.c.success, sa.Integer)))
                .group_by(outcomes.c.entry_id)).all() if e is not None}
            n_out, n_ok = conn.execute(sa.select(sa.func.count(), sa.func.sum(
                sa.cast(outcomes.c.success, sa.Integer)))).one()
            n_img = conn.execute(sa.select(sa.func.count()).where(outcomes.c.image.is_not(None))).scalar_one()
            n_det = conn.execute(sa.select(sa.func.count()).select_from(detections)).scalar_one()
        lines = [{"id": int(e), "label": lab, "created_at": float(ts), "failures": int(fcount.get(e, 0)),
                  "outcomes": ocount.get(int(e), (0, 0))[0], "successes": ocount.get(int(e), (0, 0))[1]}
                 for e, lab, ts in erows]
        return {"num_entries": len(lines), "num_failures": int(sum(fcount.values())),
                "num_outcomes": int(n_out), "num_successes": int(n_ok or 0), "num_images": int(n_img),
                "num_detections": int(n_det), "schema_version": SCHEMA_VERSION,
                "hand": self.hand.to_dict(), "template": dict(self.geometry.__dict__), "entries": lines}

    def iter_outcomes(self, with_images_only: bool = False) -> Iterator[dict[str, Any]]:
        """Every stored outcome (oldest first): grasp_id, success, entry_id, pose (4,4), width, template
        heights/types (n,n; None for a GPD grasp), image (uint8 C x 60 x 60 or None), representation; for GPD
        fine-tuning."""
        n = self.geometry.n
        q = sa.select(outcomes).order_by(outcomes.c.id)
        if with_images_only:
            q = q.where(outcomes.c.image.is_not(None))
        with self._connect() as conn:
            for r in conn.execute(q):
                img = None
                if r.image is not None:
                    img = np.frombuffer(r.image, np.uint8).reshape(json.loads(r.image_shape))
                yield {"grasp_id": r.grasp_id, "success": bool(r.success), "entry_id": r.entry_id,
                       "pose": np.frombuffer(r.pose, np.float64).reshape(4, 4), "width": float(r.width),
                       "heights": np.frombuffer(r.heights, np.float32).reshape(n, n) if r.heights else None,
                       "types": np.frombuffer(r.types, np.uint8).reshape(n, n) if r.types else None,
                       "image": img, "representation": r.representation}

    def _check_template(self, heights: NDArray[Any], types: NDArray[Any], field: str) -> None:
        t = self.geometry.num_tiles
        if np.asarray(heights).size != t or np.asarray(types).size != t:
            raise TemplateError(f"{field}: expected {t} tiles (n = {self.geometry.n})")


def parse_grasp_id(grasp_id: object) -> tuple[str, int]:
    """'<detection id>.<index>' -> (detection id, index); TemplateError naming grasp_id otherwise."""
    if not isinstance(grasp_id, str) or grasp_id.count(".") != 1:
        raise TemplateError(f"grasp_id must look like '<detection id>.<index>', got {grasp_id!r}")
    det, _, k = grasp_id.partition(".")
    if not det or not k.isdigit() or len(det) > 32:
        raise TemplateError(f"grasp_id must look like '<detection id>.<index>', got {grasp_id!r}")
    return det, int(k)
