"""Failure scenarios of `physgs perceive` against local fake servers (issue 17), with counts.

    python benchmarks/faults_scenarios.py [--requests 200] [--seed 0] [--out results/faults.json]

1. **Structured output on a fuzz server.** A local chat-completions server whose replies are faulty in the
   ways model replies are (prose around the JSON, fences, truncated or single-quoted JSON, wrong keys,
   unknown materials, refusals, empty replies, ...), drawn from a fixed, seeded fault mix (the content is
   faulty in 6 of 12 equally likely kinds; plain text adds 7 faults of form in 14 kinds). Like vLLM's or
   Ollama's constrained decoding, it keeps a reply *syntactically* JSON when asked for ``json_object`` and
   makes it conform to the schema when asked for ``json_schema``; what it says inside stays random. The
   client is run with main's request (``json_object``), with this branch's (``json_schema``), against a
   server that refuses ``json_schema`` (the client falls back), and with no response_format. A reply is
   *invalid* when validation keeps no candidate from it, and *off-schema* when it does not parse as
   ``perception.answer.Answer``. The fault mix is invented: the counts show what asking for the schema
   buys against a server that enforces it, not how often a real model errs.
2. **Drip server.** Headers, then one byte per second: the time one request takes with
   ``--vlm.timeout-s 3 --vlm.max-retries 0`` (main: until the server stops).
3. **Two runs at once** on one small dataset (``--wait-for-lock``): requests the server saw vs masks.
"""

from __future__ import annotations

import argparse
import json
import random
import sys
import tempfile
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]

from physgs_nerfstudio.materials import load_library
from physgs_nerfstudio.perception.answer import Answer
from physgs_nerfstudio.perception.prompts import PromptConfig, build_request
from physgs_nerfstudio.perception.validate import Validator, extract_json
from physgs_nerfstudio.perception.vlm import OpenAIBackend, OpenAIConfig, VLMError

# ----------------------------------------------------------------------------------------------- fuzz server


def _candidate(rng: random.Random, material: str) -> dict:
    return {
        "material": material,
        "confidence": round(rng.uniform(0.05, 1.0), 2),
        "density": round(rng.lognormvariate(7.5, 1.0), 1),
        "kinetic_friction": round(rng.uniform(0.1, 0.9), 2),
        "shore_hardness": round(rng.uniform(10, 95), 0),
        "shore_scale": rng.choice(["A", "D", "00"]),
        "youngs_modulus": float(f"{rng.lognormvariate(20, 3):.3g}"),
        "thickness_m": rng.choice([None, 0.002]),
    }


def _good(rng: random.Random, names: list[str]) -> dict:
    return {
        "caption": "a part",
        "candidates": [_candidate(rng, rng.choice(names)) for _ in range(rng.randint(1, 3))],
    }


def _json_faults(rng: random.Random, names: list[str]) -> dict:
    """A JSON object with faulty content (what JSON mode still lets through)."""
    kind = rng.choice(["clean"] * 6 + ["unknown material", "wrong keys", "no candidates", "strings",
                                      "candidate not an object", "list of names"])  # fmt: skip
    ans = _good(rng, names)
    if kind == "unknown material":
        for c in ans["candidates"]:
            c["material"] = rng.choice(["unobtainium", "shiny stuff", "some kind of metal", "N/A"])
    elif kind == "wrong keys":
        ans = {"object": "part", "guess": ans["candidates"][0]["material"], "certainty": "high"}
    elif kind == "no candidates":
        ans = {"caption": "cannot tell"}
    elif kind == "strings":
        for c in ans["candidates"]:
            c["confidence"] = "very likely"
            c["material"] = 7
    elif kind == "candidate not an object":
        ans["candidates"] = [c["material"] for c in ans["candidates"]]
    elif kind == "list of names":
        ans = {"materials": "; ".join(c["material"] for c in ans["candidates"])}
    return ans


def _text_faults(rng: random.Random, names: list[str]) -> str:
    """Free text with faults of form on top of the JSON ones."""
    body = json.dumps(_json_faults(rng, names))
    kind = rng.choice(["as is"] * 7 + ["prose", "fenced", "truncated", "single quotes", "trailing comma",
                                      "refusal", "empty"])  # fmt: skip
    if kind == "prose":
        return f"Sure! Looking at the highlighted part, here is my analysis:\n{body}\nLet me know if..."
    if kind == "fenced":
        return f"```json\n{body}\n```"
    if kind == "truncated":
        return body[: len(body) // 2]
    if kind == "single quotes":
        return body.replace('"', "'")
    if kind == "trailing comma":
        return body[:-1] + ",}"
    if kind == "refusal":
        return "I'm sorry, I cannot determine the material of this object from the image."
    if kind == "empty":
        return ""
    return body


class FuzzServer:
    """Chat completions with fuzzed answers (module docstring); ``refuse`` lists the response_format types
    it answers 400 to."""

    def __init__(self, names: list[str], seed: int, refuse: tuple[str, ...] = ()):
        self.requests: list[str | None] = []
        lock = threading.Lock()
        server = self

        class Handler(BaseHTTPRequestHandler):
            def log_message(self, *args):
                pass

            def do_POST(self):
                body = json.loads(self.rfile.read(int(self.headers.get("Content-Length", 0))))
                fmt = (body.get("response_format") or {}).get("type")
                with lock:
                    index = len(server.requests)
                    server.requests.append(fmt)
                if fmt in refuse:
                    return self._reply(400, {"error": {"message": f"response_format {fmt} is not supported"}})
                rng = random.Random(seed * 100_003 + index)
                if fmt == "json_schema":
                    schema = body["response_format"]["json_schema"]["schema"]
                    enum = schema["properties"]["candidates"]["items"]["properties"]["material"].get("enum")
                    text = json.dumps(_good(rng, enum or names))  # constrained decoding: always on schema
                elif fmt == "json_object":
                    text = json.dumps(_json_faults(rng, names))
                else:
                    text = _text_faults(rng, names)
                msg = {"role": "assistant", "content": text}
                self._reply(200, {"choices": [{"index": 0, "message": msg}], "usage": {"prompt_tokens": 1}})

            def _reply(self, status: int, payload: dict) -> None:
                data = json.dumps(payload).encode()
                self.send_response(status)
                self.send_header("Content-Type", "application/json")
                self.send_header("Content-Length", str(len(data)))
                self.end_headers()
                self.wfile.write(data)

        self.httpd = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.httpd.daemon_threads = True
        threading.Thread(target=self.httpd.serve_forever, daemon=True).start()
        self.url = f"http://127.0.0.1:{self.httpd.server_address[1]}/v1"

    def close(self) -> None:
        self.httpd.shutdown()
        self.httpd.server_close()


def _request(names: list[str]):
    import numpy as np

    img = np.random.default_rng(0).integers(0, 255, (32, 40, 3), dtype=np.uint8)
    mask = np.zeros((32, 40), bool)
    mask[8:20, 10:30] = True
    return build_request("images/f0.png", 0, "part", img, mask, names, "indoor", PromptConfig())


def _off_schema(text: str) -> bool:
    value, _ = extract_json(text)
    try:
        Answer.model_validate(value)
        return False
    except Exception:  # noqa: BLE001
        return True


def structured_output(n: int, seed: int) -> list[dict]:
    library = load_library("indoor")
    names = list(library.names)
    validator = Validator(library)
    request = _request(names)
    rows = []
    cases = [("main: json_object", "json_object", ()), ("this branch: json_schema", "json_schema", ()),
             ("server refuses json_schema", "json_schema", ("json_schema",)),
             ("no response_format", "none", ())]  # fmt: skip
    for label, first, refuse in cases:
        srv = FuzzServer(names, seed, refuse)
        be = OpenAIBackend(
            OpenAIConfig(base_url=srv.url, api_key_env="", response_format=first, max_retries=0),
            material_names=names,
        )
        invalid = off_schema = 0
        for _ in range(n):
            text = be.query(request).text
            invalid += not validator(text).candidates
            off_schema += _off_schema(text)
        srv.close()
        sent = sorted({str(f) for f in srv.requests})
        rows.append({"case": label, "replies": n, "invalid": invalid, "off_schema": off_schema,
                     "http_requests": len(srv.requests), "formats_sent": sent})  # fmt: skip
    return rows


# ----------------------------------------------------------------------------------------------- drip, two runs


def drip(deadline_s: float = 3.0) -> dict:
    stop = threading.Event()

    class Handler(BaseHTTPRequestHandler):
        def log_message(self, *args):
            pass

        def do_POST(self):
            self.rfile.read(int(self.headers.get("Content-Length", 0)))
            try:
                self.wfile.write(b"HTTP/1.1 200 OK\r\nContent-Length: 100000\r\n\r\n")
                while not stop.is_set():
                    self.wfile.write(b" ")
                    self.wfile.flush()
                    stop.wait(1.0)
            except OSError:
                pass

    httpd = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
    httpd.daemon_threads = True
    threading.Thread(target=httpd.serve_forever, daemon=True).start()
    be = OpenAIBackend(OpenAIConfig(base_url=f"http://127.0.0.1:{httpd.server_address[1]}/v1", api_key_env="",
                                    timeout_s=deadline_s, max_retries=0))  # fmt: skip
    t0 = time.monotonic()
    try:
        be.query(_request(["oak"]))
        outcome = "answered"
    except VLMError as err:
        outcome = str(err)[:120]
    elapsed = time.monotonic() - t0
    stop.set()
    httpd.shutdown()
    httpd.server_close()
    return {"deadline_s": deadline_s, "elapsed_s": round(elapsed, 2), "outcome": outcome}


def two_runs() -> dict:
    from perception_scene import make_scene
    from perception_server import FakeServer, ok

    from physgs_nerfstudio.perception import PerceptionConfig, run_perception

    with tempfile.TemporaryDirectory() as tmp, FakeServer(lambda i, b: (*ok()[:3], 0.2)) as srv:
        root = make_scene(Path(tmp) / "scene", num_views=2)
        cfg = PerceptionConfig(data=root, vlm=OpenAIConfig(base_url=srv.base_url, api_key_env=""),
                               progress=False, wait_for_lock=True)  # fmt: skip
        results = []
        threads = [threading.Thread(target=lambda: results.append(run_perception(cfg))) for _ in range(2)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        lines = (root / "observations.jsonl").read_text().splitlines()
        return {"masks": results[0].masks, "requests": len(srv.requests), "observation_lines": len(lines),
                "calls_per_run": sorted(r.calls for r in results)}  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--requests", type=int, default=200)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    report = {"structured_output": structured_output(args.requests, args.seed), "drip": drip(),
              "two_runs": two_runs()}  # fmt: skip
    print(f"1. structured output, fuzz server, {args.requests} replies each (seed {args.seed})")
    print(f"   {'case':32s} {'invalid':>8s} {'off-schema':>11s} {'HTTP requests':>14s}  formats sent")
    for r in report["structured_output"]:
        print(f"   {r['case']:32s} {r['invalid']:8d} {r['off_schema']:11d} {r['http_requests']:14d}  "
              f"{', '.join(r['formats_sent'])}")  # fmt: skip
    d = report["drip"]
    print(
        f"2. drip server, --vlm.timeout-s {d['deadline_s']:g}: request ended after {d['elapsed_s']} s ({d['outcome']})"
    )
    t = report["two_runs"]
    print(f"3. two runs at once: {t['requests']} requests for {t['masks']} masks, {t['observation_lines']} "
          f"observation lines, calls per run {t['calls_per_run']}")  # fmt: skip
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(report, indent=2))


if __name__ == "__main__":
    main()
