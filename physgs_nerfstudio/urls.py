"""URLs as they may be shown or stored: without the password of ``user:password@host``.

Every URL this project writes (run summaries, logs, error messages) goes through :func:`redact_url` or,
for free text, :func:`redact_urls`; the credentials themselves are split off by :func:`split_userinfo` and
only ever travel in an ``Authorization`` header.
"""

from __future__ import annotations

import re
from urllib.parse import unquote, urlsplit, urlunsplit

REDACTED = "***"

_URL_WITH_USERINFO = re.compile(r"(?P<scheme>[A-Za-z][A-Za-z0-9+.\-]*://)(?P<userinfo>[^/?#@\s]*)@")


def split_userinfo(url: str) -> tuple[str, str | None, str | None]:
    """``url`` without its userinfo, and the (percent-decoded) user and password (None when absent)."""
    parts = urlsplit(url)
    if "@" not in parts.netloc:
        return url, None, None
    userinfo, _, hostport = parts.netloc.rpartition("@")
    user, sep, password = userinfo.partition(":")
    clean = urlunsplit((parts.scheme, hostport, parts.path, parts.query, parts.fragment))
    return clean, unquote(user), (unquote(password) if sep else None)


def redact_url(url: str) -> str:
    """``url`` with the userinfo (``user:password@``) replaced by ``***@``; other URLs unchanged."""
    return redact_urls(url)


def redact_urls(text: str) -> str:
    """Every ``scheme://userinfo@`` in free text with the userinfo replaced by ``***``."""
    if not isinstance(text, str) or "@" not in text:
        return text
    return _URL_WITH_USERINFO.sub(lambda m: f"{m.group('scheme')}{REDACTED}@", text)
