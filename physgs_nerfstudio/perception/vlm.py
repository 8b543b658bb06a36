"""VLM backends behind one protocol: ``query(request) -> VLMResponse``.

* :class:`OpenAIBackend` - any OpenAI-compatible ``/chat/completions`` endpoint with image input (OpenAI,
  vLLM, Ollama, llama.cpp server, ...), standard library only (transport.py). Each HTTP request has a
  wall-clock deadline (``timeout_s``: connect, upload, wait and the whole reply) and a cap on the reply's
  size; retries with exponential backoff and jitter on 408/409/429/5xx, timeouts, connection errors and
  unreadable replies (``Retry-After`` / ``retry-after-ms`` honoured, capped); the first 401/403 stops
  every further request (:class:`VLMAuthError`); at most ``max_concurrency`` requests in flight per
  backend where one is given; structured output ``response_format`` json_schema (strict, from answer.py) ->
  json_object -> none, moving down for the rest of the run when the server refuses one (HTTP 400 naming it); token
  accounting from ``usage`` and a cost estimate from configurable $/1k-token rates. The API key is read from
  the environment variable named by ``api_key_env`` and is redacted from every message this module
  produces, as is any ``user:password@`` of the URL (urls.py).
* :class:`CachedBackend` - wraps a backend with the disk cache (cache.py).
* ``replay`` - see replay.py (answers only from the cache; a miss raises :class:`ReplayMiss`).
* ``simulated`` - see simulated.py (generated scenes only; every output flagged ``simulated``).

Each backend is built by its config's ``setup(data, library)`` (:class:`OpenAIConfig`,
``replay.ReplayConfig``, ``simulated.SimulatedConfig``); the perception config chooses one by its type.
"""

from __future__ import annotations

import base64
import email.utils
import http.client
import json
import logging
import os
import random
import re
import threading
import time
import urllib.parse
from collections.abc import Callable
from contextlib import nullcontext
from dataclasses import dataclass, field
from typing import Any, Literal, Protocol

from ..advanced import Advanced
from ..errors import PhysGSError
from ..urls import redact_url, redact_urls, split_userinfo
from .answer import response_format
from .cache import ResponseCache, request_key
from .prompts import VLMRequest
from .transport import DeadlineExceeded, ReplyTooLarge
from .transport import post as http_post

logger = logging.getLogger(__name__)


# ---------------------------------------------------------------------------------------------------------
# protocol
# ---------------------------------------------------------------------------------------------------------


MAX_TOKENS_REPORTED = 10**9
"""the largest token count of one reply that is believed (a larger one is capped)"""


@dataclass
class Usage:
    prompt_tokens: int = 0
    completion_tokens: int = 0
    total_tokens: int = 0

    @classmethod
    def from_dict(cls, d: dict | None) -> Usage:
        d = d or {}

        def _int(v: Any) -> int:  # a count the server reports: 0 when it is not one (1e999, NaN, text)
            try:
                return min(MAX_TOKENS_REPORTED, max(0, int(v)))
            except (TypeError, ValueError, OverflowError):
                return 0

        p, c = _int(d.get("prompt_tokens")), _int(d.get("completion_tokens"))
        t = _int(d.get("total_tokens")) or p + c
        return cls(p, c, t)

    def to_dict(self) -> dict[str, int]:
        return {
            "prompt_tokens": self.prompt_tokens,
            "completion_tokens": self.completion_tokens,
            "total_tokens": self.total_tokens,
        }


@dataclass
class VLMResponse:
    text: str
    usage: Usage = field(default_factory=Usage)
    cached: bool = False
    simulated: bool = False
    key: str = ""
    """Cache key of the request ('' when not computed)."""


class VLMBackend(Protocol):
    name: str
    """Backend id used in cache keys and observation records ("openai", "simulated", ...)."""
    model: str
    variant: str
    """Configuration fingerprint that changes answers (cache key part); '' for real endpoints."""
    simulated: bool

    def query(self, request: VLMRequest) -> VLMResponse: ...

    def cost_usd(self, usage: Usage) -> float:
        """Estimated cost of an answer's token usage (0 where nothing is paid)."""
        ...


class RateLimiter(Protocol):
    """Shared request/token budget (``physgs batch`` injects one; docs/architecture.md, "Batch").
    ``acquire(1, 0)`` blocks before each HTTP request; ``acquire(0, tokens)`` charges a response's tokens."""

    def acquire(self, requests: int, tokens: int) -> None: ...


class _NoRateLimit:
    def acquire(self, requests: int, tokens: int) -> None:
        return None


rate_limiter: RateLimiter = _NoRateLimit()
"""The limiter every OpenAIBackend built from now on uses (set with :func:`set_rate_limiter`)."""


def set_rate_limiter(limiter: RateLimiter | None) -> None:
    global rate_limiter
    rate_limiter = limiter if limiter is not None else _NoRateLimit()


class VLMError(PhysGSError, RuntimeError):
    """A request failed for good (after retries); the message never contains the API key."""


class VLMAuthError(VLMError):
    """The server refused the credentials (HTTP 401 / 403): the run stops, nothing more is sent."""


class ReplayMiss(VLMError):
    """The replay backend found no cached answer for a request."""


def key_for(backend_name: str, model: str, variant: str, request: VLMRequest) -> str:
    return request_key(
        backend_name,
        model,
        variant,
        request.system,
        request.text,
        request.image_hashes(),
        request.schema_version,
    )


# ---------------------------------------------------------------------------------------------------------
# secrets
# ---------------------------------------------------------------------------------------------------------


class Secret:
    """Holds an API key; its repr/str never show it."""

    __slots__ = ("_value",)

    def __init__(self, value: str):
        self._value = value

    def reveal(self) -> str:
        return self._value

    def __bool__(self) -> bool:
        return bool(self._value)

    def __repr__(self) -> str:
        return "Secret('***')" if self._value else "Secret('')"

    __str__ = __repr__

    def __reduce__(self):  # never pickled into caches or subprocesses
        raise TypeError("Secret cannot be pickled")


_TOKENISH = re.compile(r"[A-Za-z0-9_\-\.]{6,}")


def redact(text: str, secrets: list[str] | tuple[str, ...]) -> str:
    """Replace each secret, and any run of 6+ key characters that is part of one (servers often echo a
    truncated key such as ``sk-...abcd1234``), with ``***``."""
    secrets = [s for s in secrets if s]
    if not secrets or not text:
        return text
    for s in secrets:
        text = text.replace(s, "***")

    def _sub(m: re.Match) -> str:
        tok = m.group(0)
        return "***" if any(tok in s for s in secrets) else tok

    return _TOKENISH.sub(_sub, text)


# ---------------------------------------------------------------------------------------------------------
# OpenAI-compatible endpoint
# ---------------------------------------------------------------------------------------------------------


@dataclass
class OpenAIConfig:
    """An OpenAI-compatible chat-completions endpoint with image input."""

    base_url: str = "https://api.openai.com/v1"
    """The endpoint's root URL, e.g. http://localhost:8000/v1 for a local vLLM server."""
    model: str = "gpt-5"
    """The model's name at the endpoint."""
    api_key_env: str = "OPENAI_API_KEY"
    """The environment variable that holds the API key ('' for a local server without a key)."""
    timeout_s: Advanced[float] = 120.0
    """Wall-clock deadline of one HTTP request: connecting, sending, waiting and reading the whole reply. A
    request still running then is cut off (and retried like a timeout)."""
    max_reply_bytes: Advanced[int] = 1_048_576
    """Largest reply body accepted; a larger one is refused without reading it all (not retried, not cached)."""
    max_retries: Advanced[int] = 5
    """Retries after the first attempt on 408/409/429/5xx, timeouts, connection errors and unreadable replies."""
    backoff_base_s: Advanced[float] = 1.0
    backoff_max_s: Advanced[float] = 60.0
    """Cap on one wait (also caps Retry-After)."""
    max_wait_s: Advanced[float] = 600.0
    """Run-wide cap on the seconds spent waiting to retry; once spent, the remaining requests fail at once."""
    basic_auth_env: str = ""
    """Name of an environment variable holding user:password for HTTP basic authentication."""
    response_format: Advanced[Literal["json_schema", "json_object", "none"]] = "json_schema"
    """Structured output asked for: json_schema (the answer's strict JSON schema, material names as an enum),
    json_object, or none. A server that refuses it (HTTP 400 naming response_format / the schema) is asked
    with the next one in this order for the rest of the run."""
    image_detail: Advanced[str] = "auto"
    """OpenAI image ``detail``: auto | low | high."""
    max_tokens: Advanced[int | None] = None
    """Completion token limit (None: server default)."""
    max_tokens_field: Advanced[str] = "max_completion_tokens"
    """Name of the limit field: max_completion_tokens (OpenAI) or max_tokens (older servers)."""
    temperature: Advanced[float | None] = None
    """None: server default (GPT-5 only accepts its default)."""
    usd_per_1k_prompt_tokens: float = 0.0
    """Price in USD per 1000 prompt tokens, for the cost estimate and --budget (0: unknown)."""
    usd_per_1k_completion_tokens: float = 0.0
    """Price in USD per 1000 completion tokens, for the cost estimate and --budget (0: unknown)."""
    seed: Advanced[int | None] = 0
    """Seed for the retry jitter."""

    def __post_init__(self) -> None:
        if self.timeout_s <= 0 or self.max_reply_bytes <= 0:
            raise ValueError("--vlm.timeout-s and --vlm.max-reply-bytes must be positive")

    def setup(self, data=None, library=None) -> OpenAIBackend:
        """The backend of this config. ``library`` (the run's material library) gives the names the answer
        schema allows; ``data`` is not needed by a real endpoint (every VLM config's ``setup`` takes both)."""
        return OpenAIBackend(self, material_names=list(library.names) if library is not None else None)


def _credentials(cfg: OpenAIConfig, base: str, user: str | None, password: str | None
                 ) -> tuple[str | None, str | None]:  # fmt: skip
    """The basic-authentication user and password: ``--vlm.basic-auth-env``'s variable (``user:password``), else the
    URL's userinfo, else ``~/.netrc``'s entry for the host (None, None: no basic authentication)."""
    if cfg.basic_auth_env:
        value = os.environ.get(cfg.basic_auth_env, "")
        if ":" not in value:
            raise VLMError(f"environment variable {cfg.basic_auth_env} (--vlm.basic-auth-env) is not set to "
                           "user:password; export it, or pass --vlm.basic-auth-env ''")  # fmt: skip
        u, _, p = value.partition(":")
        return u, p
    if user is not None:
        return user, password
    import netrc

    host = urllib.parse.urlsplit(base).hostname or ""
    try:
        entry = netrc.netrc().authenticators(host)
    except (OSError, netrc.NetrcParseError):  # no ~/.netrc, or one that cannot be read
        return None, None
    return (entry[0], entry[2]) if entry else (None, None)


RESPONSE_FORMATS = ("json_schema", "json_object", "none")
_FORMAT_REFUSAL = re.compile(r"response_format|json_schema|json_object|structured|schema", re.IGNORECASE)
_FELL_BACK = object()


def _retry_after_s(headers: Any) -> float | None:
    if headers is None:
        return None
    ms = headers.get("retry-after-ms")
    if ms:
        try:
            return max(0.0, float(ms) / 1000.0)
        except ValueError:
            pass
    ra = headers.get("Retry-After")
    if not ra:
        return None
    try:
        return max(0.0, float(ra))
    except ValueError:
        try:
            when = email.utils.parsedate_to_datetime(ra)
            return max(0.0, when.timestamp() - time.time())
        except (TypeError, ValueError):
            return None


def _message_text(body: dict) -> str:
    choices = body.get("choices") or []
    if not choices:
        raise ValueError("response has no choices")
    msg = choices[0].get("message") or {}
    content = msg.get("content")
    if isinstance(content, list):  # content parts
        content = "".join(p.get("text", "") for p in content if isinstance(p, dict))
    if content is None:
        refusal = msg.get("refusal")
        return "" if refusal is None else json.dumps({"refusal": str(refusal)})
    return str(content)


class OpenAIBackend:
    name = "openai"
    variant = ""
    simulated = False

    def __init__(
        self,
        config: OpenAIConfig | None = None,
        sleep: Callable[[float], None] = time.sleep,
        material_names: list[str] | None = None,
        max_concurrency: int | None = None,
    ):
        """``max_concurrency``: requests this backend keeps in flight at once, whatever its callers' threads
        (None: as many as they send; a perception run's ``max_concurrency`` bounds its own pool)."""
        self.config = cfg = config or OpenAIConfig()
        self.model = cfg.model
        base, user, password = split_userinfo(cfg.base_url.strip())
        if urllib.parse.urlsplit(base).scheme not in ("http", "https"):
            raise VLMError(f"--vlm.base-url {redact_url(cfg.base_url)!r} is not an http(s) URL")
        self._url = base.rstrip("/") + "/chat/completions"
        self.url = redact_url(cfg.base_url.strip()).rstrip("/") + "/chat/completions"
        """The endpoint as it may be shown (userinfo redacted)."""
        if cfg.api_key_env:
            value = os.environ.get(cfg.api_key_env, "")
            if not value:
                raise VLMError(
                    f"environment variable {cfg.api_key_env} is not set: export it with your API key "
                    f"(export {cfg.api_key_env}=...), name another with --vlm.api-key-env, or pass "
                    "--vlm.api-key-env '' for a keyless local server."
                )
            self._key = Secret(value)
        else:
            self._key = Secret("")
        if user is not None and password:
            logger.warning("the password in --vlm.base-url is visible to other users of this machine in the process "
                           "list; put user:password in an environment variable named by --vlm.basic-auth-env, or in "
                           "~/.netrc, instead")  # fmt: skip
        user, password = _credentials(cfg, base, user, password)
        self._basic = None if user is None or self._key else Secret(
            base64.b64encode(f"{user}:{password or ''}".encode()).decode("ascii")
        )  # fmt: skip
        self._secrets = [s for s in (self._key.reveal(), password, self._basic and self._basic.reveal()) if s]
        self._sleep = sleep
        self._material_names = material_names
        self._format_level = RESPONSE_FORMATS.index(cfg.response_format)
        self._refused: str | None = None
        """The message of a 401/403 answer: every later query fails with it without a request."""
        self._waited = 0.0
        """Seconds this backend has waited to retry, across all requests (``max_wait_s``)."""
        self._gave_up: str | None = None
        """Why the run stopped retrying (``max_wait_s`` spent): every later query fails with it at once."""
        self._lock = threading.Lock()
        self._slots = threading.BoundedSemaphore(max(1, max_concurrency)) if max_concurrency else nullcontext()
        self._rng = random.Random(cfg.seed)
        self.rate_limiter = rate_limiter
        # statistics (thread-safe through _lock)
        self.http_requests = 0
        self.retries = 0
        self.failures = 0
        self.usage = Usage()

    def __repr__(self) -> str:
        return f"OpenAIBackend(url={self.url!r}, model={self.model!r}, key={self._key!r})"

    @property
    def response_format(self) -> str:
        """The structured-output mode requests are sent with now (after any fallback)."""
        return RESPONSE_FORMATS[self._format_level]

    # -- helpers ---------------------------------------------------------------------------------
    def _redact(self, text: str) -> str:
        text = "".join(c if c.isprintable() else " " for c in str(text))  # a server's NUL, CR, escape bytes
        return redact_urls(redact(text, self._secrets))

    def cost_usd(self, usage: Usage) -> float:
        c = self.config
        return (
            usage.prompt_tokens / 1000 * c.usd_per_1k_prompt_tokens
            + usage.completion_tokens / 1000 * c.usd_per_1k_completion_tokens
        )

    def _payload(self, request: VLMRequest, fmt: str) -> bytes:
        cfg = self.config
        content: list[dict] = [{"type": "text", "text": request.text}]
        for data in request.images:
            url = f"data:{request.mime};base64," + base64.b64encode(data).decode("ascii")
            content.append({"type": "image_url", "image_url": {"url": url, "detail": cfg.image_detail}})
        body: dict[str, Any] = {
            "model": cfg.model,
            "messages": [{"role": "system", "content": request.system}, {"role": "user", "content": content}],
        }
        rf = response_format(fmt, self._material_names)
        if rf is not None:
            body["response_format"] = rf
        if cfg.max_tokens is not None:
            body[cfg.max_tokens_field] = int(cfg.max_tokens)
        if cfg.temperature is not None:
            body["temperature"] = float(cfg.temperature)
        return json.dumps(body).encode("utf-8")

    def _post(self, data: bytes) -> tuple[int, Any, bytes]:
        headers = {"Content-Type": "application/json"}
        if self._key:
            headers["Authorization"] = "Bearer " + self._key.reveal()
        elif self._basic:
            headers["Authorization"] = "Basic " + self._basic.reveal()
        with self._lock:
            self.http_requests += 1
        cfg = self.config
        return http_post(self._url, data, headers, deadline_s=cfg.timeout_s, max_bytes=cfg.max_reply_bytes)

    def _backoff(self, attempt: int, retry_after: float | None) -> float:
        cfg = self.config
        if retry_after is not None:
            return min(cfg.backoff_max_s, retry_after)
        with self._lock:
            jitter = 1.0 + 0.25 * self._rng.random()
        return min(cfg.backoff_max_s, cfg.backoff_base_s * (2**attempt) * jitter)

    def _spend_wait(self, request: VLMRequest, delay: float, problem: str) -> None:
        """Count ``delay`` against the run-wide ``max_wait_s``; past it, this and every later request fail."""
        with self._lock:
            if self._gave_up is None and self._waited + delay > self.config.max_wait_s:
                self._gave_up = self._redact(
                    f"stopped retrying: this run already waited {self._waited:.0f} s for the server "
                    f"(--vlm.max-wait-s {self.config.max_wait_s:g}; last: {problem[:200]}); the answers received "
                    "are cached, rerun later to ask the rest")  # fmt: skip
            if self._gave_up is not None:
                self.failures += 1
                raise VLMError(f"{request.describe()}: {self._gave_up}")
            self._waited += delay

    def _fail(self, message: str, error: type[VLMError] = VLMError) -> VLMError:
        with self._lock:
            self.failures += 1
        return error(self._redact(message))

    def _answer(self, body: bytes) -> VLMResponse:
        """The response of a 200 reply (ValueError / TypeError / AttributeError when unreadable)."""
        parsed = json.loads(body.decode("utf-8"))
        text = _message_text(parsed)
        usage = Usage.from_dict(parsed.get("usage"))
        self.rate_limiter.acquire(0, usage.total_tokens)
        with self._lock:
            self.usage = Usage(
                self.usage.prompt_tokens + usage.prompt_tokens,
                self.usage.completion_tokens + usage.completion_tokens,
                self.usage.total_tokens + usage.total_tokens,
            )
        return VLMResponse(text=text, usage=usage, cached=False, simulated=False)

    def _refuse(self, request: VLMRequest, status: int, snippet: str) -> VLMAuthError:
        cfg = self.config
        fix = (
            f"check the API key in ${cfg.api_key_env} (--vlm.api-key-env names another variable)"
            if cfg.api_key_env
            else "this server wants an API key: export it and pass --vlm.api-key-env NAME"
        )
        message = (
            f"{request.describe()}: HTTP {status} from {self.url}: the server refused the credentials "
            f"({snippet[:200].strip()}); {fix}. Stopped at the first refusal."
        )
        err = self._fail(message, VLMAuthError)
        with self._lock:
            self._refused = str(err)
        return err

    def _fall_back(self, level: int, snippet: str) -> None:
        """The server refused response_format ``RESPONSE_FORMATS[level]``: use the next one from now on."""
        with self._lock:
            if self._format_level == level:
                self._format_level = level + 1
                logger.warning(
                    "%s refused response_format=%s (%s); asking with %s for the rest of this run",
                    self.url, RESPONSE_FORMATS[level], self._redact(snippet[:200]),
                    RESPONSE_FORMATS[level + 1],
                )  # fmt: skip

    def _attempt(self, request: VLMRequest, level: int) -> VLMResponse | object | tuple[str, float | None]:
        """One HTTP request: the response, ``_FELL_BACK`` (ask again with the next response format), or
        (problem, Retry-After) for a retryable failure; raises VLMError for a final one."""
        cfg = self.config
        try:
            status, headers, body = self._post(self._payload(request, RESPONSE_FORMATS[level]))
        except ReplyTooLarge as err:
            raise self._fail(f"{request.describe()}: reply from {self.url} refused: {err} "
                             "(--vlm.max-reply-bytes)") from None  # fmt: skip
        except DeadlineExceeded as err:
            return f"no complete reply within --vlm.timeout-s {cfg.timeout_s:g} s ({err})", None
        except (OSError, http.client.HTTPException) as err:
            return f"{type(err).__name__}: {getattr(err, 'reason', err)}", None
        if status == 200:
            try:
                return self._answer(body)
            except (ValueError, AttributeError, TypeError) as err:
                return f"unreadable reply ({type(err).__name__}: {str(err)[:120]})", None
        snippet = body[:2000].decode("utf-8", errors="replace")
        if status in (401, 403):
            raise self._refuse(request, status, snippet)
        if status in (400, 422) and level + 1 < len(RESPONSE_FORMATS) and _FORMAT_REFUSAL.search(snippet):
            self._fall_back(level, snippet)
            return _FELL_BACK
        if status not in (408, 409, 429) and status < 500:
            raise self._fail(f"{request.describe()}: HTTP {status} from {self.url}: {snippet[:500]}")
        return f"HTTP {status}: {snippet[:200]}", _retry_after_s(headers)

    # -- protocol ----------------------------------------------------------------------------------
    def query(self, request: VLMRequest) -> VLMResponse:
        cfg = self.config
        attempt = 0
        with self._slots:
            while True:
                if self._refused is not None:
                    raise VLMAuthError(self._refused)
                if self._gave_up is not None:
                    raise VLMError(self._gave_up)
                self.rate_limiter.acquire(1, 0)
                outcome = self._attempt(request, self._format_level)
                if isinstance(outcome, VLMResponse):
                    return outcome
                if outcome is _FELL_BACK:
                    continue
                problem, retry_after = outcome  # type: ignore[misc]
                if attempt >= cfg.max_retries:
                    raise self._fail(f"{request.describe()}: giving up after {attempt + 1} attempts ({problem})")
                delay = self._backoff(attempt, retry_after)
                self._spend_wait(request, delay, problem)
                logger.info("retrying %s in %.2fs after %s", request.describe(), delay, self._redact(problem))
                with self._lock:
                    self.retries += 1
                attempt += 1
                self._sleep(delay)


# ---------------------------------------------------------------------------------------------------------
# cache wrapper / replay
# ---------------------------------------------------------------------------------------------------------


class CachedBackend:
    """Answers from the disk cache when it can, else asks ``inner`` and caches the answer; an answer longer
    than ``max_text_chars`` (which validation rejects for its size) is passed on but not cached."""

    def __init__(self, inner: VLMBackend, cache: ResponseCache, max_text_chars: int | None = None):
        self.inner = inner
        self.cache = cache
        self.max_text_chars = max_text_chars
        self.name = inner.name
        self.model = inner.model
        self.variant = inner.variant
        self.simulated = bool(inner.simulated)

    def cost_usd(self, usage: Usage) -> float:
        return float(self.inner.cost_usd(usage))

    def key(self, request: VLMRequest) -> str:
        return key_for(self.name, self.model, self.variant, request)

    def lookup(self, request: VLMRequest) -> VLMResponse | None:
        key = self.key(request)
        entry = self.cache.get(key)
        if entry is None:
            return None
        return VLMResponse(
            entry.text, Usage.from_dict(entry.usage), cached=True, simulated=entry.simulated, key=key
        )

    def query(self, request: VLMRequest) -> VLMResponse:
        hit = self.lookup(request)
        if hit is not None:
            return hit
        key = self.key(request)
        response = self.inner.query(request)
        if self.max_text_chars is not None and len(response.text) > self.max_text_chars:
            logger.warning("%s: answer of %d characters not cached (over %d)", request.describe(),
                           len(response.text), self.max_text_chars)  # fmt: skip
            return VLMResponse(response.text, response.usage, cached=False, simulated=response.simulated, key=key)
        self.cache.put(
            key,
            response.text,
            response.usage.to_dict(),
            response.simulated,
            meta={
                "backend": self.name,
                "model": self.model,
                "view": request.view,
                "mask_id": request.mask_id,
            },
        )
        return VLMResponse(response.text, response.usage, cached=False, simulated=response.simulated, key=key)
