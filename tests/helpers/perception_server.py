"""A local OpenAI-compatible chat-completions server (127.0.0.1, port 0) for the perception tests.

``behaviour(request_index, body) -> (status, headers, payload, delay_s)``; default: answer 200 with a valid
JSON candidate list. Counts requests; records Authorization headers it saw (to check the key is sent).
"""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Callable
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from typing_extensions import Self

ANSWER = {
    "caption": "a red ceramic body",
    "object": "mug",
    "candidates": [
        {
            "material": "ceramic",
            "confidence": 0.7,
            "density": 2300,
            "kinetic_friction": 0.5,
            "shore_hardness": 90,
            "shore_scale": "D",
            "youngs_modulus": 7e10,
            "thickness_m": None,
        },
        {
            "material": "porcelain",
            "confidence": 0.3,
            "density": 2400,
            "kinetic_friction": 0.5,
            "shore_hardness": 92,
            "shore_scale": "D",
            "youngs_modulus": 8e10,
            "thickness_m": None,
        },
    ],
}


def ok(text: str | None = None, usage=(100, 20)) -> tuple[int, dict, dict, float]:
    body = {
        "id": "x",
        "object": "chat.completion",
        "choices": [
            {
                "index": 0,
                "message": {"role": "assistant", "content": text if text is not None else json.dumps(ANSWER)},
            }
        ],
        "usage": {
            "prompt_tokens": usage[0],
            "completion_tokens": usage[1],
            "total_tokens": usage[0] + usage[1],
        },
    }
    return 200, {}, body, 0.0


class FakeServer:
    """The server; a subclass changes what it answers by overriding :meth:`handler`."""

    def __init__(self, behaviour: Callable[[int, dict], tuple[int, dict, dict, float]] | None = None):
        self.behaviour = behaviour or (lambda i, body: ok())
        self.requests: list[dict] = []
        self.auth: list[str] = []
        self.lock = threading.Lock()
        self.httpd = ThreadingHTTPServer(("127.0.0.1", 0), self.handler())
        self.httpd.daemon_threads = True
        self.thread = threading.Thread(target=self.httpd.serve_forever, daemon=True)

    def handler(self) -> type[BaseHTTPRequestHandler]:
        """The request handler class: answers every POST with ``behaviour``."""
        server = self

        class Handler(BaseHTTPRequestHandler):
            def log_message(self, *args):  # quiet
                pass

            def do_POST(self):
                length = int(self.headers.get("Content-Length", 0))
                raw = self.rfile.read(length)
                try:
                    body = json.loads(raw)
                except ValueError:
                    body = {}
                with server.lock:
                    index = len(server.requests)
                    server.requests.append(body)
                    server.auth.append(self.headers.get("Authorization", ""))
                status, headers, payload, delay = server.behaviour(index, body)
                if delay:
                    time.sleep(delay)
                data = json.dumps(payload).encode()
                try:
                    self.send_response(status)
                    for k, v in headers.items():
                        self.send_header(k, v)
                    self.send_header("Content-Type", "application/json")
                    self.send_header("Content-Length", str(len(data)))
                    self.end_headers()
                    self.wfile.write(data)
                except (BrokenPipeError, ConnectionResetError):
                    pass

        return Handler

    @property
    def base_url(self) -> str:
        host, port = self.httpd.server_address[:2]
        return f"http://{host}:{port}/v1"

    def __enter__(self) -> Self:
        self.thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self.httpd.shutdown()
        self.httpd.server_close()
