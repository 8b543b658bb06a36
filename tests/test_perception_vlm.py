"""OpenAI-compatible backend over a real socket (local server), cache, replay, key hygiene."""

from __future__ import annotations

import json
import logging

import numpy as np
import pytest
from helpers.perception_server import FakeServer, ok

from physgs_nerfstudio.perception.replay import ReplayConfig
from physgs_nerfstudio.perception.cache import ResponseCache
from physgs_nerfstudio.perception.prompts import PromptConfig, build_request
from physgs_nerfstudio.perception.vlm import (
    CachedBackend,
    OpenAIBackend,
    OpenAIConfig,
    ReplayMiss,
    VLMError,
    redact,
)

KEY = "sk-test-SECRETKEY-1234567890abcdef"


@pytest.fixture
def request_():
    rng = np.random.default_rng(0)
    img = rng.integers(0, 255, (32, 40, 3), dtype=np.uint8)
    mask = np.zeros((32, 40), bool)
    mask[8:20, 10:30] = True
    return build_request(
        "images/f0.png", 3, "part", img, mask, ["ceramic", "steel"], "indoor", PromptConfig()
    )


def _backend(server, monkeypatch, max_concurrency=None, **kw):
    monkeypatch.setenv("PHYSGS_TEST_KEY", KEY)
    cfg = OpenAIConfig(
        base_url=server.base_url,
        model="test-model",
        api_key_env="PHYSGS_TEST_KEY",
        backoff_base_s=0.01,
        backoff_max_s=0.05,
        timeout_s=2.0,
        **kw,
    )
    return OpenAIBackend(cfg, max_concurrency=max_concurrency)


def test_success_usage_and_payload(request_, monkeypatch):
    with FakeServer() as srv:
        be = _backend(srv, monkeypatch, usd_per_1k_prompt_tokens=1.0, usd_per_1k_completion_tokens=2.0)
        resp = be.query(request_)
    assert json.loads(resp.text)["candidates"][0]["material"] == "ceramic"
    assert resp.usage.prompt_tokens == 100 and resp.usage.completion_tokens == 20 and not resp.simulated
    assert be.cost_usd(resp.usage) == pytest.approx(0.1 + 0.04)
    body = srv.requests[0]
    assert body["model"] == "test-model" and body["response_format"]["type"] == "json_schema"
    assert body["response_format"]["json_schema"]["strict"] is True
    content = body["messages"][1]["content"]
    assert content[1]["image_url"]["url"].startswith("data:image/png;base64,")
    assert srv.auth[0] == f"Bearer {KEY}"


def test_retries_on_429_and_500_honour_retry_after(request_, monkeypatch):
    script = {
        0: (429, {"Retry-After": "0.05"}, {"error": "slow down"}, 0.0),
        1: (500, {}, {"error": "boom"}, 0.0),
        2: (503, {}, {"error": "busy"}, 0.0),
    }
    sleeps = []
    with FakeServer(lambda i, b: script.get(i, ok())) as srv:
        be = _backend(srv, monkeypatch)
        be._sleep = lambda s: sleeps.append(s)
        resp = be.query(request_)
    assert len(srv.requests) == 4 and be.retries == 3 and be.http_requests == 4
    assert sleeps[0] == pytest.approx(0.05)  # Retry-After honoured
    assert sleeps[1] < sleeps[2] or sleeps[2] == 0.05  # exponential (capped)
    assert "ceramic" in resp.text


def test_timeout_is_retried(request_, monkeypatch):
    with FakeServer(lambda i, b: (200, {}, ok()[2], 1.0) if i == 0 else ok()) as srv:
        monkeypatch.setenv("PHYSGS_TEST_KEY", KEY)
        be = OpenAIBackend(
            OpenAIConfig(
                base_url=srv.base_url,
                api_key_env="PHYSGS_TEST_KEY",
                timeout_s=0.3,
                backoff_base_s=0.01,
                backoff_max_s=0.02,
            )
        )
        resp = be.query(request_)
    assert be.retries == 1 and len(srv.requests) == 2 and "ceramic" in resp.text


def test_gives_up_after_max_retries_without_leaking_key(request_, monkeypatch, caplog):
    caplog.set_level(logging.DEBUG)
    with FakeServer(lambda i, b: (500, {}, {"error": f"bad key {KEY} and {KEY[-10:]}"}, 0.0)) as srv:
        be = _backend(srv, monkeypatch, max_retries=2)
        with pytest.raises(VLMError) as err:
            be.query(request_)
    assert len(srv.requests) == 3
    assert KEY not in str(err.value) and KEY[-10:] not in str(err.value) and "***" in str(err.value)
    assert KEY not in caplog.text and KEY[-10:] not in caplog.text
    assert KEY not in repr(be)


def test_client_error_not_retried_and_json_mode_auto_disabled(request_, monkeypatch):
    def behave(i, body):
        if "response_format" in body:
            return 400, {}, {"error": {"message": "response_format not supported"}}, 0.0
        return ok()

    with FakeServer(behave) as srv:
        be = _backend(srv, monkeypatch)
        assert "ceramic" in be.query(request_).text
        assert "ceramic" in be.query(request_).text
    formats = [b.get("response_format", {}).get("type") for b in srv.requests]
    assert formats == ["json_schema", "json_object", None, None]  # each refused once, then plain text
    with FakeServer(lambda i, b: (401, {}, {"error": "unauthorized"}, 0.0)) as srv:
        be = _backend(srv, monkeypatch)
        with pytest.raises(VLMError, match="HTTP 401"):
            be.query(request_)
    assert len(srv.requests) == 1


def test_missing_key_env_is_a_clear_error(monkeypatch):
    monkeypatch.delenv("PHYSGS_NO_SUCH_KEY", raising=False)
    with pytest.raises(VLMError, match="PHYSGS_NO_SUCH_KEY"):
        OpenAIBackend(OpenAIConfig(api_key_env="PHYSGS_NO_SUCH_KEY"))


def test_cache_prevents_repeat_calls_and_replay(request_, monkeypatch, tmp_path, caplog):
    caplog.set_level(logging.DEBUG)
    cache = ResponseCache(tmp_path / "cache")
    with FakeServer() as srv:
        be = CachedBackend(_backend(srv, monkeypatch), cache)
        first = be.query(request_)
        second = be.query(request_)
    assert len(srv.requests) == 1 and not first.cached and second.cached and first.text == second.text
    assert first.key == second.key and len(first.key) == 64
    replay = CachedBackend(ReplayConfig(model="test-model").setup(), cache)
    assert replay.query(request_).text == first.text
    other = build_request(
        "images/f1.png",
        7,
        "part",
        np.zeros((8, 8, 3), np.uint8),
        np.ones((8, 8), bool),
        ["ceramic"],
        "indoor",
    )
    with pytest.raises(ReplayMiss) as miss:
        replay.query(other)
    assert (
        "images/f1.png" in str(miss.value)
        and "mask 7" in str(miss.value)
        and replay.key(other) in str(miss.value)
    )
    for f in (tmp_path / "cache").rglob("*"):
        if f.is_file():
            assert KEY not in f.read_text() and KEY[-8:] not in f.read_text()
    assert KEY not in caplog.text


def test_concurrency_is_bounded(request_, monkeypatch):
    import threading
    from concurrent.futures import ThreadPoolExecutor

    active, peak, lock = [0], [0], threading.Lock()

    def behave(i, body):
        with lock:
            active[0] += 1
            peak[0] = max(peak[0], active[0])
        import time

        time.sleep(0.05)
        with lock:
            active[0] -= 1
        return ok()

    with FakeServer(behave) as srv:
        be = _backend(srv, monkeypatch, max_concurrency=2)
        with ThreadPoolExecutor(6) as pool:
            list(pool.map(lambda _: be.query(request_), range(6)))
    assert len(srv.requests) == 6 and peak[0] <= 2


def test_redact_fragments():
    assert redact(f"key={KEY}; tail {KEY[-12:]}", [KEY]) == "key=***; tail ***"
    assert redact("nothing here", [KEY]) == "nothing here"
