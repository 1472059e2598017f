"""The options streamed clouds and CDR queries are detected with, changed at run time: a JSON put or query on
<prefix>/config (guarded like every writer; a refused config's error goes to <prefix>/errors and the log, and the
options in force stay)."""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from typing import Any

from graspd.server.logs import begin_request
from graspd.server.problems import Problem, internal_error, too_large
from graspd.server.services.lifecycle import Lifecycle
from graspd.server.services.ros_stream import MAX_CONFIG_BYTES, StreamOptions, parse_options
from graspd.server.settings import Settings

from .exposure import ZenohSetupError
from .gate import Gate, attachment, guarded_parse, payload_of, size_of

log = logging.getLogger("graspd.server")


class RuntimeOptions:
    """The stream options in force (settings' GRASPD_STREAM_OPTIONS, then the last accepted config) and the
    <prefix>/config entrances that change them."""

    def __init__(self, settings: Settings, gate: Gate, lifecycle: Lifecycle, key: str,
                 put_error: Callable[[Problem], None], refuse: Callable[[str], None]) -> None:
        self.settings = settings
        self.gate = gate
        self.lifecycle = lifecycle
        self.key = key
        self._put_error = put_error  # an error body on <prefix>/errors
        self._refuse = refuse  # a put without the token: counted, logged at most every 10 s
        self._lock = threading.Lock()
        base = {"num_samples": settings.stream_num_samples, **settings.stream_options}
        try:
            self._options = parse_options(base, {}, (settings.stream_viewpoint,))
        except Problem as exc:
            raise ZenohSetupError(f"GRASPD_STREAM_OPTIONS: {exc.field}: {exc.message}") from None
        self._base = self._options.source

    @property
    def current(self) -> StreamOptions:
        """The options streamed clouds and CDR queries are detected with now."""
        with self._lock:
            return self._options

    def set(self, payload: bytes) -> StreamOptions:
        """Validate a config payload (Problem naming the field) and make it the stream options."""
        options = guarded_parse(lambda p: parse_options(p, self._base, (self.settings.stream_viewpoint,)), payload)
        with self._lock:
            self._options = options
        log.info("stream options set", extra={"transport": "zenoh", "options": options.source})
        return options

    def _payload(self, size: int, read: Callable[[], bytes]) -> bytes:
        if size > MAX_CONFIG_BYTES:
            raise too_large("config", size, MAX_CONFIG_BYTES, "payload")
        return read()

    def on_put(self, sample: Any) -> None:
        """A JSON put on <prefix>/config: with a token set it must carry it (whatever zenoh_stream_token says);
        an invalid config is logged and its error put on <prefix>/errors; the options in force stay."""
        try:
            if not self.gate.authorized(attachment(sample)):
                self._refuse("config put")
                return
            self.set(self._payload(size_of(sample.payload), lambda: bytes(sample.payload.to_bytes())))
        except Problem as exc:
            log.warning("stream config refused", extra={"transport": "zenoh", "status": exc.status,
                                                        "field": exc.field, "error": exc.message})
            self._put_error(exc)
        except Exception:  # never take the node down
            log.exception("stream config failed")

    def on_query(self, query: Any) -> None:
        """A query on <prefix>/config: empty, the options in force; with a JSON payload, set them first.  The
        reply is the options in force, or an error reply naming the field (the options in force stay)."""
        begin_request()  # one request id per query (the callback runs in a fresh context)
        tracked = self.lifecycle.track("zenoh", "config")
        try:
            self.gate.check(query, self.key)
            payload = self._payload(size_of(query.payload), lambda: payload_of(query))
            options = self.set(payload) if payload.strip() else self.current
            self.gate.reply(query, tracked, None, options.to_json(), self.key)
        except Problem as exc:
            if exc.status != 401:
                log.warning("stream config refused", extra={"transport": "zenoh", "status": exc.status,
                                                            "field": exc.field, "error": exc.message})
            self.gate.reply(query, tracked, exc)
        except Exception:
            rid = "-" if tracked.ctx is None else tracked.ctx.id
            log.exception("zenoh config failed", extra={"request_id": rid})
            self.gate.reply(query, tracked, internal_error(rid))
