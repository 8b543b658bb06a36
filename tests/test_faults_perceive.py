"""Hostile and careless input to `physgs perceive` (issue 17, perception side): each numbered item of the
issue is a test here. Local servers only (tests/helpers/perception_server.py and the drip server below)."""

from __future__ import annotations

import errno
import json
import logging
import os
import subprocess
import threading
import time
from http.server import BaseHTTPRequestHandler
from pathlib import Path

import numpy as np
import pytest
from helpers.perception_scene import make_scene
from helpers.perception_server import ANSWER, FakeServer, ok
from PIL import Image

from physgs_nerfstudio.cli import entrypoint
from physgs_nerfstudio.errors import DatasetError, PhysGSError
from physgs_nerfstudio.fusion import transaction
from physgs_nerfstudio.perception import PerceptionConfig, run_perception
from physgs_nerfstudio.perception.answer import Answer, strict_json_schema
from physgs_nerfstudio.perception.cache import ResponseCache
from physgs_nerfstudio.perception.images import BadFrame, read_image
from physgs_nerfstudio.perception.lock import LOCK_FILE, LockHeld, LockInfo
from physgs_nerfstudio.perception.pipeline import NoObservations
from physgs_nerfstudio.perception.prompts import PromptConfig, build_request
from physgs_nerfstudio.perception.vlm import (
    CachedBackend,
    OpenAIBackend,
    OpenAIConfig,
    VLMAuthError,
    VLMError,
)
from physgs_nerfstudio.urls import redact_urls, split_userinfo

KEY = "sk-faults-SECRET-0123456789abcdef"
OUTPUTS = ("materials.json", "transforms.json", "transforms.json.bak", "materials")


def _vlm(url: str, **kw) -> OpenAIConfig:
    kw = {"model": "m", "api_key_env": "PHYSGS_FAULT_KEY", "timeout_s": 5.0, "backoff_base_s": 0.01,
          "backoff_max_s": 0.02, **kw}  # fmt: skip
    return OpenAIConfig(base_url=url, **kw)


def _config(root: Path, url: str, vlm: dict | None = None, **kw) -> PerceptionConfig:
    return PerceptionConfig(data=root, vlm=_vlm(url, **(vlm or {})), progress=False, **kw)


@pytest.fixture(autouse=True)
def _key(monkeypatch):
    monkeypatch.setenv("PHYSGS_FAULT_KEY", KEY)


def _outputs(root: Path) -> dict[str, bytes]:
    """The files `perceive` writes into the dataset for others to read (bytes per relative path)."""
    out = {}
    for name in OUTPUTS:
        p = root / name
        files = [p] if p.is_file() else sorted(f for f in p.rglob("*") if f.is_file()) if p.is_dir() else []
        out.update({str(f.relative_to(root)): f.read_bytes() for f in files})
    return out


def _strays(root: Path) -> list[Path]:
    return [p for p in root.rglob("*") if p.name.startswith(transaction.STAGING_PREFIX) or p.suffix == ".tmp"]


def _request():
    img = np.random.default_rng(0).integers(0, 255, (32, 40, 3), dtype=np.uint8)
    mask = np.zeros((32, 40), bool)
    mask[8:20, 10:30] = True
    return build_request(
        "images/f0.png", 3, "part", img, mask, ["ceramic", "steel"], "indoor", PromptConfig()
    )


# ------------------------------------------------------------------------------------------------ 1. hang
class DripServer(FakeServer):
    """A server that answers 200 and then sends one byte per second: of the body (``mode="body"``), of the
    header block (``"headers"``), or sends 64 KiB chunks without end (``"endless"``)."""

    def __init__(self, mode: str):
        self.mode = mode
        self.stop = threading.Event()
        super().__init__()

    def handler(self) -> type[BaseHTTPRequestHandler]:
        server, mode = self, self.mode

        class Handler(BaseHTTPRequestHandler):
            def log_message(self, *args):
                pass

            def do_POST(self):
                self.rfile.read(int(self.headers.get("Content-Length", 0)))
                with server.lock:
                    server.requests.append({})
                head = b"HTTP/1.1 200 OK\r\nContent-Type: application/json\r\n"
                try:
                    if mode == "headers":
                        for b in head + b"X-Slow: " + b"a" * 100:
                            self._send(bytes([b]), 1.0)
                    elif mode == "body":
                        self._send(head + b"Content-Length: 100000\r\n\r\n", 0)
                        while not server.stop.is_set():
                            self._send(b" ", 1.0)
                    else:
                        self._send(head + b"Connection: close\r\n\r\n", 0)
                        while not server.stop.is_set():
                            self._send(b" " * 65536, 0)
                except OSError:
                    pass

            def _send(self, data: bytes, pause: float):
                if server.stop.is_set():
                    raise BrokenPipeError
                self.wfile.write(data)
                self.wfile.flush()
                if pause:
                    server.stop.wait(pause)

        return Handler

    def __exit__(self, *exc):
        self.stop.set()
        super().__exit__(*exc)


@pytest.mark.parametrize("mode", ["body", "headers"])
def test_1_drip_server_request_ends_at_its_deadline(mode):
    with DripServer(mode) as srv:
        be = OpenAIBackend(_vlm(srv.base_url, timeout_s=3.0, max_retries=0))
        t0 = time.monotonic()
        with pytest.raises(VLMError, match="timeout-s 3"):
            be.query(_request())
        elapsed = time.monotonic() - t0
    assert 2.5 <= elapsed <= 3.0 + 2.0, elapsed


def test_1_drip_server_perceive_run_finishes_within_deadline(tmp_path):
    root = make_scene(tmp_path / "scene", num_views=1)
    with DripServer("body") as srv:
        t0 = time.monotonic()
        with pytest.raises(NoObservations):  # the run ends, non-zero, the dataset untouched
            run_perception(
                _config(root, srv.base_url, {"timeout_s": 3.0, "max_retries": 0}, prompt="baseline")
            )
        elapsed = time.monotonic() - t0
    assert elapsed <= 3.0 + 2.0, elapsed
    assert len(srv.requests) == 1 and not (root / "materials.json").exists()


def test_1_endless_reply_is_cut_at_the_size_cap():
    with DripServer("endless") as srv:
        be = OpenAIBackend(_vlm(srv.base_url, timeout_s=20.0, max_reply_bytes=200_000, max_retries=3))
        t0 = time.monotonic()
        with pytest.raises(VLMError, match="max-reply-bytes"):
            be.query(_request())
    assert time.monotonic() - t0 < 10 and len(srv.requests) == 1  # refused at once, not retried


# ------------------------------------------------------------------------------------------------ 2. lock
def test_2_two_concurrent_runs_ask_each_mask_once(tmp_path):
    root = make_scene(tmp_path / "scene", num_views=2)
    with FakeServer(lambda i, b: (*ok()[:3], 0.3)) as srv:  # slow answers: the runs overlap
        results, errors = {}, []

        def go(name):
            try:
                results[name] = run_perception(_config(root, srv.base_url, wait_for_lock=True))
            except Exception as err:  # noqa: BLE001
                errors.append(err)

        threads = [threading.Thread(target=go, args=(n,)) for n in ("a", "b")]
        for t in threads:
            t.start()
        for t in threads:
            t.join(120)
    assert not errors, errors
    masks = results["a"].masks
    assert masks > 0 and len(srv.requests) == masks  # request count == mask count
    lines = [json.loads(x) for x in (root / "observations.jsonl").read_text().splitlines()]
    keys = [(o["view"], o["mask_id"], o["material"]) for o in lines]
    assert len(keys) == len(set(keys)) == 2 * masks  # each observation written once (2 candidates a mask)
    assert sorted(r.calls for r in results.values()) == [0, masks]
    assert not (root / LOCK_FILE).exists()


def _write_lock(root: Path, pid: int, host: str | None = None) -> Path:
    info = LockInfo.mine()
    info.pid = pid
    if host:
        info.host = host
    path = root / LOCK_FILE
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(info.__dict__))
    return path


def test_2_second_run_refuses_naming_the_holder(tmp_path, capsys):
    root = make_scene(tmp_path / "scene", num_views=1)
    holder = subprocess.Popen(["sleep", "60"])
    try:
        _write_lock(root, holder.pid)
        with FakeServer() as srv:
            with pytest.raises(LockHeld, match=f"pid {holder.pid}.*--wait-for-lock"):
                run_perception(_config(root, srv.base_url))
            with pytest.raises(SystemExit) as exit_:
                entrypoint(["perceive", "--data", str(root), "--no-progress", "vlm:openai", "--vlm.base-url",
                            srv.base_url, "--vlm.api-key-env", "PHYSGS_FAULT_KEY"])  # fmt: skip
        assert len(srv.requests) == 0
    finally:
        holder.kill()
        holder.wait()
    err = capsys.readouterr().err.strip()
    assert exit_.value.code == 1 and len(err.splitlines()) == 1 and f"pid {holder.pid}" in err
    assert "Traceback" not in err


def test_2_stale_locks_are_taken_over(tmp_path):
    root = make_scene(tmp_path / "scene", num_views=1)
    dead = subprocess.Popen(["true"])
    dead.wait()
    _write_lock(root, dead.pid)
    with FakeServer() as srv:
        result = run_perception(_config(root, srv.base_url, prompt="baseline"))
        assert result.calls == 1 and not (root / LOCK_FILE).exists()
        # an empty lock file (a kill right after creating it) is stale once old, held while young
        (root / LOCK_FILE).write_text("")
        with pytest.raises(LockHeld, match="starting"):
            run_perception(_config(root, srv.base_url, prompt="baseline"))
        old = time.time() - 60
        os.utime(root / LOCK_FILE, (old, old))
        run_perception(_config(root, srv.base_url, prompt="baseline"))
        # a lock of another host is never presumed stale
        _write_lock(root, 1, host="some-other-host")
        with pytest.raises(LockHeld, match="some-other-host"):
            run_perception(_config(root, srv.base_url, prompt="baseline"))


# ------------------------------------------------------------------------------------------------ 4. transaction
def _answer(material: str) -> str:
    cands = [dict(ANSWER["candidates"][0], material=material, confidence=1.0)]
    return json.dumps({"caption": "x", "candidates": cands})


@pytest.mark.parametrize("where", ["first map", "materials.json", "commit record"])
def test_4_disk_full_during_rerun_leaves_the_dataset_as_it_was(tmp_path, monkeypatch, where):
    root = make_scene(tmp_path / "scene", num_views=2)
    real = transaction.write_file
    before: dict[str, bytes] = {}

    def full_disk(path: Path, data: bytes) -> None:
        name = Path(path).name
        hit = {"first map": "labels" in str(path), "materials.json": name == "materials.json",
               "commit record": transaction.JOURNAL in name}[where]  # fmt: skip
        if hit and before:
            raise OSError(errno.ENOSPC, "No space left on device", str(path))
        real(path, data)

    monkeypatch.setattr(transaction, "write_file", full_disk)
    with FakeServer(lambda i, b: ok(_answer("ceramic"))) as srv:
        run_perception(_config(root, srv.base_url))
    before.update(_outputs(root))
    assert json.loads(before["materials.json"])["materials"][0]["name"] == "ceramic"
    steel = FakeServer(lambda i, b: ok(_answer("steel")))  # another model: other answers, new ids
    with steel as srv, pytest.raises(PhysGSError, match="disk is full.*left as it was"):
        run_perception(_config(root, srv.base_url, {"model": "m2"}, overwrite=True))
    assert _outputs(root) == before  # all old files, byte for byte, and no new one
    assert _strays(root) == []
    monkeypatch.setattr(transaction, "write_file", real)
    with FakeServer(lambda i, b: ok(_answer("steel"))) as srv:  # space again: the rerun completes
        run_perception(_config(root, srv.base_url, {"model": "m2"}))
    assert json.loads((root / "materials.json").read_text())["materials"][0]["name"] == "steel"


def test_4_a_committed_update_interrupted_while_moving_is_finished(tmp_path):
    (tmp_path / "materials.json").write_text("old")
    txn = transaction.DatasetTransaction(tmp_path)
    txn.write_text("materials.json", "new")
    txn.write_text("materials/labels/a.png", "A")
    transaction.atomic_write_bytes(
        txn.staging / transaction.JOURNAL, json.dumps({"files": txn.files}).encode()
    )
    uncommitted = transaction.DatasetTransaction(tmp_path)  # recovers the first one on creation
    assert (tmp_path / "materials.json").read_text() == "new" and (
        tmp_path / "materials/labels/a.png"
    ).exists()
    uncommitted.write_text("materials.json", "never")  # staged, never committed (a kill)
    transaction.recover(tmp_path)
    assert (tmp_path / "materials.json").read_text() == "new" and _strays(tmp_path) == []


def test_4_real_full_tmpfs(tmp_path):
    if os.geteuid() != 0:
        pytest.skip("mounting a tmpfs needs root")
    mnt = tmp_path / "mnt"
    mnt.mkdir()
    mount = ["mount", "-t", "tmpfs", "-o", "size=4m", "tmpfs", str(mnt)]
    if subprocess.run(mount, capture_output=True, check=False).returncode:
        pytest.skip("cannot mount a tmpfs here")
    try:
        root = make_scene(mnt / "scene", num_views=2)
        cache = tmp_path / "cache"  # the response cache lives elsewhere
        with FakeServer(lambda i, b: ok(_answer("ceramic"))) as srv:
            run_perception(_config(root, srv.base_url, cache_dir=cache))
        before = _outputs(root)
        need = sum(-(-len(b) // 4096) * 4096 for k, b in before.items() if k.startswith("materials"))
        st = os.statvfs(mnt)
        free = st.f_bavail * st.f_frsize
        with open(mnt / "filler", "wb") as fh:  # leave room for the observations, not for the maps
            fh.write(b"\0" * max(0, free - need // 2))
        steel = FakeServer(lambda i, b: ok(_answer("steel")))
        with steel as srv, pytest.raises(PhysGSError, match="disk is full"):
            run_perception(_config(root, srv.base_url, {"model": "m2"}, cache_dir=cache, overwrite=True))
        assert _outputs(root) == before and _strays(root) == []
    finally:
        subprocess.run(["umount", str(mnt)], check=False)


# ------------------------------------------------------------------------------------------------ 7. images
def test_7_16bit_and_float_images_are_scaled_not_clipped(tmp_path):
    ramp = (np.arange(48 * 64).reshape(48, 64) * 21).astype(np.uint16)  # 0 .. 64491
    Image.fromarray(ramp).save(tmp_path / "a16.png")
    assert Image.open(tmp_path / "a16.png").mode.startswith("I;16")
    got = read_image(tmp_path / "a16.png")
    assert got.shape == (48, 64, 3) and got.dtype == np.uint8
    np.testing.assert_array_equal(got[..., 0], np.round(ramp / 65535.0 * 255).astype(np.uint8))
    assert (got == 255).mean() < 0.05  # main read it as all white
    ramp_f = np.linspace(0, 1, 48 * 64, dtype=np.float32).reshape(48, 64)
    Image.fromarray(ramp_f, mode="F").save(tmp_path / "f.tiff")
    np.testing.assert_array_equal(
        read_image(tmp_path / "f.tiff")[..., 1], np.round(ramp_f * 255).astype(np.uint8)
    )
    hdr = ramp_f * 1000 - 200  # outside [0, 1]: its own range
    Image.fromarray(hdr, mode="F").save(tmp_path / "hdr.tiff")
    got = read_image(tmp_path / "hdr.tiff")[..., 2]
    assert got.min() == 0 and got.max() == 255 and abs(int(got[24, 0]) - 127) <= 2


def test_7_a_16bit_frame_is_sent_as_the_scaled_image(tmp_path):
    root = make_scene(tmp_path / "scene", num_views=1)
    rgb = np.asarray(Image.open(root / "images/frame_00000.png"))
    grey16 = (rgb.mean(-1) * 257).astype(np.uint16)  # the same picture in 16 bits
    Image.fromarray(grey16).save(root / "images/frame_00000.png")
    with FakeServer() as srv:
        result = run_perception(_config(root, srv.base_url))
    assert result.masks >= 3 and result.observations > 0  # main: one all-white mask, empty labels


def test_7_unreadable_images_are_rejected_with_one_line(tmp_path):
    (tmp_path / "z.png").write_bytes(b"")
    (tmp_path / "junk.png").write_bytes(b"\x89PNG\r\n\x1a\n" + b"junk" * 20)
    for name, why in (("z.png", "empty"), ("junk.png", "cannot be read")):
        with pytest.raises(BadFrame, match=why) as err:
            read_image(tmp_path / name, f"images/{name}")
        assert f"images/{name}" in str(err.value) and "\n" not in str(err.value)


# ------------------------------------------------------------------------------------------------ 8. all failed
def _untouched(root: Path, before: dict[str, bytes]) -> None:
    assert _outputs(root) == before and not (root / "materials.json").exists()
    assert "material_path" not in (root / "transforms.json").read_text()
    assert not (root / "observations.jsonl").exists()


@pytest.mark.parametrize("status", [401, 403])
def test_8_credentials_refused_stops_at_the_first_request(tmp_path, capsys, status):
    root = make_scene(tmp_path / "scene", num_views=2)
    before = _outputs(root)
    with FakeServer(lambda i, b: (status, {}, {"error": {"message": "invalid api key"}}, 0.0)) as srv:
        with pytest.raises(VLMAuthError, match=r"API key in \$PHYSGS_FAULT_KEY"):
            run_perception(_config(root, srv.base_url, max_concurrency=1))
        assert len(srv.requests) == 1
        with pytest.raises(SystemExit) as exit_:
            entrypoint(["perceive", "--data", str(root), "--no-progress", "--max-concurrency", "1", "vlm:openai",
                        "--vlm.base-url", srv.base_url, "--vlm.api-key-env", "PHYSGS_FAULT_KEY"])  # fmt: skip
    err = capsys.readouterr().err.strip()
    assert exit_.value.code == 1 and len(err.splitlines()) == 1 and "API key" in err and KEY not in err
    _untouched(root, before)


@pytest.mark.parametrize(
    "reply",
    [
        (429, {"Retry-After": "0"}, {"error": "rate limited"}, 0.0),
        (200, {}, {"choices": "not a list of choices"}, 0.0),
        (500, {}, {"error": "down"}, 0.0),
    ],
    ids=["endless 429", "unreadable body", "500"],
)
def test_8_no_observations_leaves_the_dataset_untouched_and_fails(tmp_path, reply):
    root = make_scene(tmp_path / "scene", num_views=1)
    before = _outputs(root)
    with (
        FakeServer(lambda i, b: reply) as srv,
        pytest.raises(NoObservations, match="were not changed") as err,
    ):
        run_perception(_config(root, srv.base_url, {"max_retries": 2}, prompt="baseline"))
    assert len(srv.requests) == 3  # retried, then given up
    assert "failed" in str(err.value)
    _untouched(root, before)


# ------------------------------------------------------------------------------------------------ 9. paths
def test_9_frames_outside_the_dataset_are_refused(tmp_path):
    root = make_scene(tmp_path / "d" / "scene", num_views=2)
    secret = tmp_path / "private.png"
    Image.fromarray(np.full((96, 128, 3), 200, np.uint8)).save(secret)
    meta = json.loads((root / "transforms.json").read_text())
    for bad in ("../../private.png", str(secret)):
        meta["frames"][1]["file_path"] = bad
        (root / "transforms.json").write_text(json.dumps(meta))
        with FakeServer() as srv:
            with pytest.raises(DatasetError, match="outside the dataset.*--allow-outside-paths"):
                run_perception(_config(root, srv.base_url, prompt="baseline"))
            assert len(srv.requests) == 0  # nothing read, nothing sent
    (root / "images/link.png").symlink_to(secret)  # a symlink out of the dataset
    meta["frames"][1]["file_path"] = "images/link.png"
    (root / "transforms.json").write_text(json.dumps(meta))
    with FakeServer() as srv:
        with pytest.raises(DatasetError, match="outside the dataset"):
            run_perception(_config(root, srv.base_url, prompt="baseline"))
        result = run_perception(_config(root, srv.base_url, prompt="baseline", allow_outside_paths=True))
    assert result.calls == 2


def test_9_symlink_loop_is_one_clear_line(tmp_path):
    root = make_scene(tmp_path / "scene", num_views=2)
    (root / "images/loop_a.png").symlink_to(root / "images/loop_b.png")
    (root / "images/loop_b.png").symlink_to(root / "images/loop_a.png")
    meta = json.loads((root / "transforms.json").read_text())
    meta["frames"][0]["file_path"] = "images/loop_a.png"
    (root / "transforms.json").write_text(json.dumps(meta))
    with FakeServer() as srv:
        result = run_perception(_config(root, srv.base_url, prompt="baseline"))
        assert len(result.skipped_frames) == 1 and "symlink loop" in result.skipped_frames[0]
        with pytest.raises(BadFrame, match="images/loop_a.png.*symlink loop"):
            run_perception(_config(root, srv.base_url, prompt="baseline", strict=True))


# ------------------------------------------------------------------------------------------------ 10. smaller
def test_10a_userinfo_of_the_url_is_never_written(tmp_path, caplog):
    caplog.set_level(logging.DEBUG)
    assert split_userinfo("http://u:p%40ss@h:1/v1") == ("http://h:1/v1", "u", "p@ss")
    assert redact_urls("at http://u:pw@h/v1.") == "at http://***@h/v1."
    root = make_scene(tmp_path / "scene", num_views=2)

    def behave(i, body):
        return (404, {}, {"error": "no such model"}, 0.0) if i == 0 else ok()

    with FakeServer(behave) as srv:
        url = srv.base_url.replace("http://", "http://alice:hunter2secret@")
        config = _config(root, url, {"api_key_env": ""}, prompt="baseline", max_concurrency=1)
        result = run_perception(config)  # the first request fails: a failure message naming the URL
        again = run_perception(config)
    assert set(srv.auth) == {"Basic YWxpY2U6aHVudGVyMnNlY3JldA=="}  # the credentials are used, as basic auth
    assert len(result.failed) == 1 and "http://***@127.0.0.1" in result.failed[0] and again.calls == 1
    texts = [caplog.text, *result.failed] + [
        f.read_text(errors="ignore") for f in root.rglob("*") if f.is_file()
    ]
    assert all("hunter2secret" not in t for t in texts)
    assert "http://***@127.0.0.1" in (root / "perception/run.json").read_text()


def test_10c_replies_rejected_for_size_are_not_cached(tmp_path):
    huge = json.dumps({"caption": "x" * 150_000, "candidates": ANSWER["candidates"]})  # > max_text_chars
    with FakeServer(lambda i, b: ok(huge)) as srv:
        cache = ResponseCache(tmp_path / "cache")
        be = CachedBackend(OpenAIBackend(_vlm(srv.base_url)), cache, max_text_chars=100_000)
        assert len(be.query(_request()).text) > 100_000
        be.query(_request())
    assert len(srv.requests) == 2 and not any(p.is_file() for p in (tmp_path / "cache").rglob("*"))
    with FakeServer(lambda i, b: ok("y" * 3_000_000)) as srv:  # over the reply cap: refused, not retried
        be = CachedBackend(OpenAIBackend(_vlm(srv.base_url)), cache, max_text_chars=100_000)
        with pytest.raises(VLMError, match="max-reply-bytes"):
            be.query(_request())
    assert len(srv.requests) == 1 and not any(p.is_file() for p in (tmp_path / "cache").rglob("*"))


# ------------------------------------------------------------------------------------------------ 12. schema
def test_12_structured_output_schema_and_fallbacks():
    schema = strict_json_schema(["ceramic", "steel"])
    item = schema["properties"]["candidates"]["items"]
    assert item["properties"]["material"]["enum"] == ["ceramic", "steel"]
    assert item["additionalProperties"] is False and set(item["required"]) == set(item["properties"])
    from physgs_nerfstudio.perception.prompts import RESPONSE_SCHEMA

    assert set(item["properties"]) == set(RESPONSE_SCHEMA["properties"]["candidates"]["items"]["properties"])
    assert set(schema["properties"]) == set(RESPONSE_SCHEMA["properties"]) == {"caption", "object", "candidates"}
    Answer.model_validate(ANSWER)  # the answer the prompt asks for fits the model

    with FakeServer() as srv:
        be = OpenAIBackend(_vlm(srv.base_url), material_names=["ceramic", "steel"])
        be.query(_request())
    rf = srv.requests[0]["response_format"]
    assert rf["type"] == "json_schema" and rf["json_schema"]["strict"] is True
    assert rf["json_schema"]["schema"] == schema

    def refuses_schema(i, body):
        if body.get("response_format", {}).get("type") == "json_schema":
            return 400, {}, {"error": {"message": "response_format.type json_schema is not supported"}}, 0.0
        return ok()

    with FakeServer(refuses_schema) as srv:
        be = OpenAIBackend(_vlm(srv.base_url))
        be.query(_request())
        be.query(_request())
    assert [b["response_format"]["type"] for b in srv.requests] == [
        "json_schema",
        "json_object",
        "json_object",
    ]
    assert be.response_format == "json_object"

    with FakeServer(lambda i, b: (400, {}, {"error": "bad image"}, 0.0)) as srv:  # not about the format
        be = OpenAIBackend(_vlm(srv.base_url))
        with pytest.raises(VLMError, match="HTTP 400"):
            be.query(_request())
    assert len(srv.requests) == 1 and be.response_format == "json_schema"


# ------------------------------------------------------------------------------------------------ 13. bad files
@pytest.mark.parametrize(
    "content, match",
    [
        ('{"frames": [', r"transforms.json is not valid JSON .*line 1"),
        ("[1, 2, 3]", r"transforms.json holds a JSON list, not an object"),
        ('{"frames": 3}', r"transforms.json has no 'frames' list"),
    ],
)
def test_13_malformed_transforms_is_one_line_naming_the_file(tmp_path, capsys, content, match):
    root = tmp_path / "scene"
    root.mkdir()
    (root / "transforms.json").write_text(content)
    with pytest.raises(DatasetError, match=match):
        run_perception(PerceptionConfig(data=root, progress=False))
    with pytest.raises(SystemExit) as exit_:
        entrypoint(["perceive", "--data", str(root), "--no-progress", "vlm:simulated"])
    err = capsys.readouterr().err.strip()
    assert exit_.value.code == 1 and len(err.splitlines()) == 1 and str(root / "transforms.json") in err


def test_13_a_missing_dataset_folder_is_one_line_and_not_created(tmp_path):
    with pytest.raises(DatasetError, match="not a directory"):
        run_perception(PerceptionConfig(data=tmp_path / "typo", progress=False))
    assert not (tmp_path / "typo").exists()


@pytest.mark.parametrize("damage", ["zero bytes", "corrupt", "missing"])
def test_13_one_bad_frame_among_many_is_skipped_and_reported(tmp_path, caplog, damage):
    root = make_scene(tmp_path / "scene", num_views=3)
    bad = root / "images/frame_00001.png"
    if damage == "zero bytes":
        bad.write_bytes(b"")
    elif damage == "corrupt":
        bad.write_bytes(bad.read_bytes()[:200])
    else:
        bad.unlink()
    with FakeServer() as srv:
        result = run_perception(_config(root, srv.base_url, prompt="baseline"))
        assert result.calls == 2 and len(result.skipped_frames) == 1
        assert "images/frame_00001.png" in result.skipped_frames[0] and "skipping a frame" in caplog.text
        frames = {f["file_path"]: f for f in json.loads((root / "transforms.json").read_text())["frames"]}
        assert "material_path" not in frames["images/frame_00001.png"]
        assert "material_path" in frames["images/frame_00000.png"]
        with pytest.raises(BadFrame, match="frame_00001"):
            run_perception(_config(root, srv.base_url, prompt="baseline", strict=True))
