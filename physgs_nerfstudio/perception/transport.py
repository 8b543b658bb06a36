"""One HTTP POST with a wall-clock deadline and a cap on the size of the reply (standard library only).

A socket timeout bounds each read, not the request: a server that sends its headers and then one byte per
second keeps ``urllib`` waiting for as long as it likes. :func:`post` gives the whole request (connect,
upload, wait, headers, body) one deadline: a watchdog timer shuts the connection's socket down when it
passes, which ends any read in progress, and the body is read in chunks, checking the deadline and the size
after each. A ``Content-Length`` above the cap is refused before the body is read.

The request goes through ``urllib``'s opener, so ``http_proxy`` / ``https_proxy`` still apply; redirects are
not followed (a chat-completions POST is never redirected on purpose, and following one would send the API
key to another host) and no status raises: the caller gets every status with its (capped) body.
"""

from __future__ import annotations

import http.client
import socket
import threading
import time
import urllib.request
from collections.abc import Mapping
from email.message import Message

CHUNK_BYTES = 64 * 1024


class DeadlineExceeded(TimeoutError):
    """The request was still running when its wall-clock deadline passed."""


class ReplyTooLarge(OSError):
    """The reply (announced or received) is larger than the cap."""


class _Watch:
    """The connection of one request, so that the watchdog can cut it off."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self.conn: http.client.HTTPConnection | None = None
        self.expired = False

    def factory(self, http_class: type[http.client.HTTPConnection]):
        def make(host: str, **kwargs) -> http.client.HTTPConnection:
            conn = http_class(host, **kwargs)
            with self._lock:
                self.conn = conn
            return conn

        return make

    def expire(self) -> None:
        """Shut the socket down (both directions): a blocked read returns at once."""
        with self._lock:
            self.expired = True
            sock = getattr(self.conn, "sock", None)
        if sock is not None:
            try:  # the plain socket's shutdown, also for an SSL socket (its own would race the reading thread)
                socket.socket.shutdown(sock, socket.SHUT_RDWR)
            except OSError:
                pass


class _HTTPHandler(urllib.request.HTTPHandler):
    def __init__(self, watch: _Watch):
        super().__init__()
        self.watch = watch

    def http_open(self, req):
        return self.do_open(self.watch.factory(http.client.HTTPConnection), req)


class _HTTPSHandler(urllib.request.HTTPSHandler):
    def __init__(self, watch: _Watch):
        super().__init__()
        self.watch = watch

    def https_open(self, req):
        return self.do_open(self.watch.factory(http.client.HTTPSConnection), req, context=self._context)


class _EveryStatus(urllib.request.HTTPErrorProcessor):
    """Hands back every response, whatever its status (no HTTPError, no redirect)."""

    def http_response(self, request, response):
        return response

    https_response = http_response


def _read_capped(resp: http.client.HTTPResponse, deadline: float, max_bytes: int, watch: _Watch) -> bytes:
    announced = resp.headers.get("Content-Length")
    if announced and announced.strip().isdigit() and int(announced) > max_bytes:
        raise ReplyTooLarge(f"the reply announces {int(announced)} bytes, more than the cap of {max_bytes}")
    chunks: list[bytes] = []
    size = 0
    while True:
        if time.monotonic() >= deadline or watch.expired:
            raise DeadlineExceeded(f"reply still arriving at the deadline ({size} bytes so far)")
        chunk = resp.read1(CHUNK_BYTES)
        if not chunk:
            break
        size += len(chunk)
        if size > max_bytes:
            raise ReplyTooLarge(f"the reply exceeds the cap of {max_bytes} bytes")
        chunks.append(chunk)
    if watch.expired:  # the watchdog's shutdown looks like the end of the body
        raise DeadlineExceeded(f"reply cut off at the deadline ({size} bytes so far)")
    return b"".join(chunks)


def post(
    url: str,
    data: bytes,
    headers: Mapping[str, str],
    *,
    deadline_s: float,
    max_bytes: int,
) -> tuple[int, Message, bytes]:
    """POST ``data``; returns (status, headers, body) for every status. Raises :class:`DeadlineExceeded`
    when the whole exchange takes longer than ``deadline_s`` seconds, :class:`ReplyTooLarge` when the body
    is longer than ``max_bytes``, and ``OSError`` / ``http.client.HTTPException`` for a broken connection."""
    start = time.monotonic()
    deadline = start + deadline_s
    watch = _Watch()
    opener = urllib.request.build_opener(_HTTPHandler(watch), _HTTPSHandler(watch), _EveryStatus())
    req = urllib.request.Request(url, data=data, method="POST")
    for k, v in headers.items():
        req.add_header(k, v)
    timer = threading.Timer(deadline_s, watch.expire)
    timer.daemon = True
    timer.start()
    try:
        try:
            resp = opener.open(req, timeout=deadline_s)
        except (OSError, http.client.HTTPException) as err:
            if watch.expired or time.monotonic() >= deadline:
                raise DeadlineExceeded(f"no complete reply headers within {deadline_s:g} s") from err
            raise
        with resp:
            try:
                body = _read_capped(resp, deadline, max_bytes, watch)
            except (OSError, http.client.HTTPException) as err:
                if isinstance(err, (DeadlineExceeded, ReplyTooLarge)):
                    raise
                if watch.expired:
                    raise DeadlineExceeded(f"reply cut off at the deadline of {deadline_s:g} s") from err
                raise
            return resp.status, resp.headers, body
    finally:
        timer.cancel()
        conn = watch.conn
        if conn is not None:
            conn.close()
