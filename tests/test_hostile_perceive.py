"""Perception's hostile inputs of issue 72 ("also broke"): a hand-edited observations.jsonl, absurd usage
counts, a server's raw control bytes, garbage lock files, an endless 429 and credentials outside the URL. Oracles:
the dataset's bytes before and after, the local server's request count and the headers it saw."""

from __future__ import annotations

import json
import os
import socket
import threading
from pathlib import Path

import pytest
from helpers.perception_scene import make_scene
from helpers.perception_server import FakeServer, ok

from physgs_nerfstudio.perception import PerceptionConfig, run_perception
from physgs_nerfstudio.perception.lock import GRACE_S, LOCK_FILE, DatasetLock, LockHeld
from physgs_nerfstudio.perception.pipeline import NoObservations
from physgs_nerfstudio.perception.prompts import PromptConfig, build_request
from physgs_nerfstudio.perception.vlm import OpenAIBackend, OpenAIConfig, Usage, VLMError

KEY_ENV = "PHYSGS_HOSTILE_KEY"


@pytest.fixture(autouse=True)
def _key(monkeypatch, tmp_path):
    monkeypatch.setenv(KEY_ENV, "sk-hostile")
    monkeypatch.setenv("HOME", str(tmp_path / "home"))  # no ~/.netrc of the machine's
    (tmp_path / "home").mkdir()


def _vlm(url: str, **kw) -> OpenAIConfig:
    kw = {"model": "m", "api_key_env": KEY_ENV, "timeout_s": 5.0, "backoff_base_s": 0.01, "backoff_max_s": 0.02, **kw}
    return OpenAIConfig(base_url=url, **kw)


def _request():
    import numpy as np

    img = np.random.default_rng(0).integers(0, 255, (32, 40, 3), dtype=np.uint8)
    mask = np.zeros((32, 40), bool)
    mask[8:20, 10:30] = True
    return build_request("images/f0.png", 3, "part", img, mask, ["ceramic", "steel"], "indoor", PromptConfig())


# ------------------------------------------------------------------------------------------ observations
def test_nan_confidences_never_replace_a_good_materials_json(tmp_path):
    root = make_scene(tmp_path / "scene", num_views=2)
    with FakeServer() as srv:
        first = run_perception(PerceptionConfig(data=root, vlm=_vlm(srv.base_url), progress=False, prompt="baseline"))
        assert first.observations > 0
        good = (root / "materials.json").read_bytes()
        assert json.loads(good)["materials"]
        obs = root / "observations.jsonl"
        lines = [json.loads(x) for x in obs.read_text().splitlines()]
        for r in lines:
            r["confidence"] = float("nan")
        obs.write_text("".join(json.dumps(r) + "\n" for r in lines))
        with pytest.raises(NoObservations) as ei:
            run_perception(PerceptionConfig(data=root, vlm=_vlm(srv.base_url), progress=False, prompt="baseline"))
    msg = str(ei.value)
    assert "observations.jsonl" in msg and "NaN" in msg and "\n" not in msg
    assert (root / "materials.json").read_bytes() == good


def test_some_nan_confidences_are_left_out_and_the_rest_fused(tmp_path, caplog):
    root = make_scene(tmp_path / "scene", num_views=2)
    with FakeServer() as srv:
        run_perception(PerceptionConfig(data=root, vlm=_vlm(srv.base_url), progress=False, prompt="baseline"))
        obs = root / "observations.jsonl"
        lines = [json.loads(x) for x in obs.read_text().splitlines()]
        lines[0]["confidence"] = float("nan")
        obs.write_text("".join(json.dumps(r) + "\n" for r in lines))
        result = run_perception(PerceptionConfig(data=root, vlm=_vlm(srv.base_url), progress=False, prompt="baseline"))
    assert result.observations == len(lines) - 1 and "1 of" in caplog.text
    assert json.loads((root / "materials.json").read_text())["materials"]


# ------------------------------------------------------------------------------------------ replies
def test_an_absurd_usage_count_keeps_the_answer():
    assert Usage.from_dict({"prompt_tokens": float("inf"), "completion_tokens": 5}).prompt_tokens == 0
    assert Usage.from_dict({"prompt_tokens": 1e300}).prompt_tokens == 10**9
    with FakeServer(lambda i, body: ok(usage=(float("inf"), 20))) as srv:  # sent as Infinity (1e999 reads the same)
        backend = OpenAIBackend(_vlm(srv.base_url))
        response = backend.query(_request())
    assert json.loads(response.text)["candidates"] and response.usage.completion_tokens == 20


class RawServer:
    """Answers every connection with ``reply`` bytes and closes it."""

    def __init__(self, reply: bytes):
        self.sock = socket.socket()
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen(8)
        self.reply = reply
        self.thread = threading.Thread(target=self._serve, daemon=True)

    def _serve(self) -> None:
        while True:
            try:
                conn, _ = self.sock.accept()
            except OSError:
                return
            with conn:
                conn.settimeout(2)
                try:
                    conn.recv(1 << 20)
                    conn.sendall(self.reply)
                except OSError:
                    pass

    @property
    def base_url(self) -> str:
        return f"http://127.0.0.1:{self.sock.getsockname()[1]}/v1"

    def __enter__(self):
        self.thread.start()
        return self

    def __exit__(self, *exc):
        self.sock.close()


def test_a_garbage_status_line_prints_no_control_bytes(caplog):
    caplog.set_level("INFO")
    with RawServer(b"\x00\rHTTP/9 \x1b[2J\x07garbage\r\n\r\n") as srv:
        backend = OpenAIBackend(_vlm(srv.base_url, max_retries=1))
        with pytest.raises(VLMError) as ei:
            backend.query(_request())
    msg = str(ei.value)
    assert "giving up" in msg and msg.isprintable(), repr(msg)
    assert all(r.getMessage().isprintable() for r in caplog.records), [r.getMessage() for r in caplog.records]


# ------------------------------------------------------------------------------------------ 429 run-wide
def test_an_endless_429_gives_up_run_wide():
    """Each request may retry max_retries times; the run as a whole stops waiting after max_wait_s."""
    slept: list[float] = []
    with FakeServer(lambda i, body: (429, {"Retry-After": "30"}, {"error": "slow down"}, 0.0)) as srv:
        backend = OpenAIBackend(_vlm(srv.base_url, backoff_max_s=60.0, max_wait_s=100.0, max_retries=5),
                                sleep=slept.append)  # fmt: skip
        with pytest.raises(VLMError, match="stopped retrying: this run already waited 90 s"):
            backend.query(_request())
        asked = len(srv.requests)
        with pytest.raises(VLMError, match="--vlm.max-wait-s 100"):
            backend.query(_request())  # the next mask: no request at all
        assert len(srv.requests) == asked
    assert slept == [30.0, 30.0, 30.0] and sum(slept) <= 100.0


# ------------------------------------------------------------------------------------------ credentials
def test_basic_credentials_from_an_environment_variable(monkeypatch):
    monkeypatch.setenv("PHYSGS_HOSTILE_BASIC", "alice:s3cret")
    with FakeServer() as srv:
        OpenAIBackend(_vlm(srv.base_url, api_key_env="", basic_auth_env="PHYSGS_HOSTILE_BASIC")).query(_request())
    import base64

    assert srv.auth == ["Basic " + base64.b64encode(b"alice:s3cret").decode()]


def test_basic_credentials_from_netrc(tmp_path):
    netrc = Path(os.environ["HOME"]) / ".netrc"
    netrc.write_text("machine 127.0.0.1 login bob password pw2\n")
    netrc.chmod(0o600)
    with FakeServer() as srv:
        OpenAIBackend(_vlm(srv.base_url, api_key_env="")).query(_request())
    import base64

    assert srv.auth == ["Basic " + base64.b64encode(b"bob:pw2").decode()]


def test_a_password_in_the_url_is_warned_about(caplog):
    OpenAIBackend(_vlm("http://carol:pw3@127.0.0.1:9/v1", api_key_env=""))
    assert "process list" in caplog.text and "pw3" not in caplog.text


# ------------------------------------------------------------------------------------------ locks
def _held(root: Path) -> str:
    with pytest.raises(LockHeld) as ei:
        DatasetLock(root).acquire()
    return str(ei.value)


def test_each_kind_of_held_lock_has_its_own_message(tmp_path):
    root = tmp_path / "d"
    (root / "perception").mkdir(parents=True)
    lock = root / LOCK_FILE
    messages = {}
    lock.write_bytes(b"")
    messages["empty"] = _held(root)
    lock.write_bytes(b"\x00garbage")
    messages["garbage"] = _held(root)
    lock.write_text(json.dumps({"pid": os.getpid()}))
    messages["pid only"] = _held(root)
    lock.write_text(json.dumps({"pid": os.getpid(), "host": socket.gethostname(), "started": "t", "command": "c"}))
    messages["live"] = _held(root)
    lock.unlink()
    lock.mkdir()
    messages["folder"] = _held(root)
    assert "still empty" in messages["empty"]
    assert "not a lock record" in messages["garbage"] and f"{GRACE_S:g} s" in messages["garbage"]
    assert f"pid {os.getpid()} (running here)" in messages["pid only"]
    assert f"pid {os.getpid()} on {socket.gethostname()}" in messages["live"]
    assert "is a folder" in messages["folder"] and "rm -r" in messages["folder"]
    assert len(set(messages.values())) == len(messages)
    assert all(m.isprintable() for m in messages.values())
