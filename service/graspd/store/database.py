"""graspd's grasp store in a database (SQLAlchemy Core; SQLite by default, PostgreSQL for a fleet): the
schema, its migrations, engines, password redaction and the npz blobs rows carry.

Tables: entries (demonstrated templates with their gripper pose relative to the template frame),
failures (the sets F_l: candidate templates whose grasp from entry l failed), detections (what each
template detection returned, so feedback can refer to a grasp by id), outcomes (every reported
outcome with its pose and, when available, its template and GPD grasp image, for fine-tuning later),
meta (the template geometry and hand the library was made for), schema_version.

Schema changes are ordered migration steps (MIGRATIONS); opening a store applies the missing ones in
one write transaction, so concurrent openers agree.  SQLite runs in WAL mode with every transaction
BEGIN IMMEDIATE and a busy timeout, so concurrent writers (threads or processes) queue instead of
losing rows.  The template library (graspd.templates) and the outcome store (graspd.store.outcomes) share one
Database.
"""

from __future__ import annotations

import io
import re
import sqlite3
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any
from urllib.parse import quote, quote_plus, unquote

import numpy as np
import sqlalchemy as sa
from numpy.typing import NDArray
from sqlalchemy.engine import Connection, Engine

from graspd.core.errors import FieldError


class StoreError(FieldError):
    """A bad store URL or argument; `field` names it (library_url, success)."""


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
        sa.Column("pose", sa.LargeBinary, nullable=False),  # float64 4x4 grasp pose (graspd.core.grasp convention)
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
        for form in sorted({password, unquote(password), quote(password, safe=""), quote_plus(password)},
                           key=len, reverse=True):
            out = out.replace(form, MASK)
    out = _URL_CREDENTIALS.sub(lambda m: f"{m['head']}:{MASK}@", out)
    return _DSN_PASSWORD.sub(lambda m: f"{m['key']}{m['eq']}{MASK}", out)


#: Text that locates a server or a file: IPv4 / bracketed IPv6 addresses (with a port), "port N", absolute paths.
_ADDRESS = re.compile(r"\[[0-9A-Fa-f:.]+\](?::\d+)?|\b\d{1,3}(?:\.\d{1,3}){3}(?::\d+)?")
_PORT = re.compile(r"(?i)\bport\s*[=:]?\s*\d+")
_PATH = re.compile(r"(?<![\w.])/(?:[\w.+\-@%]+/)*[\w.+\-@%]+")
_USER = re.compile(r"(?i)\b(?P<key>user(?:name)?|role)(?P<sep>\s*[=:]?\s*\"?)(?P<name>[\w.\-]+)")


def scrub(text: str, url: str | None = None) -> str:
    """text with nothing that locates or identifies the store: every password (redact_text), every URL, and the
    configured URL's user, host, port and database replaced by <url>, <user>, <host>, <port>, <database>; any
    other address, 'port N', 'user "x"' and absolute path masked too.  For log lines: driver messages quote all
    of these ('connection to server at "db.lan" (10.0.0.5), port 5432 failed: FATAL: password authentication
    failed for user "graspd"')."""
    out = redact_text(text, url)
    parts: dict[str, str] = {}
    if url:
        try:
            u = sa.engine.make_url(url)
            parts = {"<user>": u.username or "", "<host>": u.host or "", "<port>": str(u.port or ""),
                     "<database>": u.database or ""}
        except Exception:  # an unparsable URL: the generic patterns below still apply
            parts = {}
        for form in {url, redact_url(url)}:
            out = out.replace(form, "<url>")
    out = re.sub(r"[A-Za-z][A-Za-z0-9+.\-]*://\S+", "<url>", out)
    for mask, value in sorted(parts.items(), key=lambda kv: -len(kv[1])):
        if len(value) >= 2:
            out = re.sub(rf"(?<![\w]){re.escape(value)}(?![\w])", mask, out)
    out = _ADDRESS.sub("<host>", out)
    out = _PORT.sub("port <port>", out)
    out = _USER.sub(lambda m: f"{m['key']}{m['sep']}<user>", out)
    return _PATH.sub("<path>", out)


#: How long an SQLite connection waits for other processes' locks (s): the busy timeout and the WAL switch's retries.
BUSY_TIMEOUT_S = 60


def _set_wal(cursor: Any) -> None:
    """Put the SQLite file in WAL mode, retrying while it is locked: switching a fresh file's journal mode takes
    an exclusive lock without calling the busy handler, so processes that create one store at once see
    "database is locked" however long the busy timeout is."""
    deadline = time.monotonic() + BUSY_TIMEOUT_S
    pause = 0.005
    while True:
        try:
            cursor.execute("PRAGMA journal_mode = WAL").fetchall()
            return
        except sqlite3.OperationalError as exc:
            if ("locked" not in str(exc) and "busy" not in str(exc)) or time.monotonic() > deadline:
                raise
            time.sleep(pause)
            pause = min(pause * 2, 0.2)


def make_engine(url: str) -> Engine:
    """An engine for url; SQLite gets WAL, a 60 s busy timeout and BEGIN IMMEDIATE transactions.  Errors
    quote the URL with its password masked."""
    if not isinstance(url, str) or not url:
        raise StoreError("library_url", f"must be an SQLAlchemy URL string, got {url!r}")  # not a secret: empty
    try:
        parsed = sa.engine.make_url(url)
    except sa.exc.ArgumentError:
        raise StoreError("library_url", f"is not an SQLAlchemy URL: {redact_url(url)!r}") from None
    if parsed.get_backend_name() != "sqlite":
        return sa.create_engine(url, pool_pre_ping=True)
    memory = parsed.database in (None, "", ":memory:")
    engine = sa.create_engine(url, connect_args={"timeout": BUSY_TIMEOUT_S, "check_same_thread": False},
                              **({"poolclass": sa.pool.StaticPool} if memory else {}))  # one shared in-memory db

    @sa.event.listens_for(engine, "connect")
    def _connect(dbapi_conn: Any, _record: Any) -> None:
        dbapi_conn.isolation_level = None  # let the "begin" hook below own transactions
        cur = dbapi_conn.cursor()
        cur.execute(f"PRAGMA busy_timeout = {BUSY_TIMEOUT_S * 1000}")
        if not memory:
            _set_wal(cur)
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
    """The arrays as .npz bytes (compressed unless compress is False)."""
    buf = io.BytesIO()
    (np.savez_compressed if compress else np.savez)(buf, **arrays)  # type: ignore[operator, arg-type]
    return buf.getvalue()


def from_npz(blob: bytes) -> dict[str, NDArray[Any]]:
    """The arrays of .npz bytes (to_npz)."""
    with np.load(io.BytesIO(blob)) as z:
        return {k: z[k] for k in z.files}


class Database:
    """The store at an SQLAlchemy URL, created and migrated on open; write and read transactions.

    An in-memory SQLite store is one shared connection: its transactions from several threads take turns."""

    def __init__(self, url: str) -> None:
        self.url = url
        self.engine = make_engine(url)
        self._lock = threading.RLock() if self.engine.pool.__class__ is sa.pool.StaticPool else None
        with self._locked():
            migrate(self.engine)

    @contextmanager
    def _locked(self) -> Iterator[None]:
        if self._lock is None:
            yield
        else:
            with self._lock:
                yield

    @contextmanager
    def begin(self) -> Iterator[Connection]:
        """A write transaction (committed on success)."""
        with self._locked(), self.engine.begin() as conn:
            yield conn

    @contextmanager
    def connect(self) -> Iterator[Connection]:
        """A read-only connection."""
        with self._locked(), self.engine.connect() as conn:
            yield conn

    def close(self) -> None:
        self.engine.dispose()
