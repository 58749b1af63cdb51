"""A webhook receiver for the tests: an HTTP server on 127.0.0.1 that records each POST and answers with
the status its policy chooses."""

from __future__ import annotations

import http.server
import threading
from collections.abc import Callable
from typing import Any

#: (headers of this delivery, every delivery so far, this one included) -> the status to answer.
Policy = Callable[[dict[str, str], list[tuple[dict[str, str], bytes]]], int]


class Receiver:
    """Records deliveries as ``(lower-cased headers, body)``; ``close()`` stops it."""

    def __init__(self, policy: Policy) -> None:
        self.deliveries: list[tuple[dict[str, str], bytes]] = []
        self.lock = threading.Lock()
        receiver = self

        class Handler(http.server.BaseHTTPRequestHandler):
            def do_POST(self) -> None:
                body = self.rfile.read(int(self.headers.get("content-length", "0")))
                headers = {k.lower(): v for k, v in self.headers.items()}
                with receiver.lock:
                    receiver.deliveries.append((headers, body))
                    status = policy(headers, list(receiver.deliveries))
                self.send_response(status)
                self.send_header("content-length", "0")
                self.end_headers()

            def log_message(self, *args: Any) -> None:
                pass

        self.server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.port = int(self.server.server_address[1])
        threading.Thread(target=self.server.serve_forever, daemon=True).start()

    @classmethod
    def scripted(cls, statuses: list[int]) -> Receiver:
        """Answers ``statuses`` in turn, then 204."""
        planned = list(statuses)
        return cls(lambda _headers, _seen: planned.pop(0) if planned else 204)

    @classmethod
    def failing_first(cls) -> Receiver:
        """Answers 500 to the first delivery of each event (``webhook-id``), 204 to the next."""

        def policy(headers: dict[str, str], seen: list[tuple[dict[str, str], bytes]]) -> int:
            same = [h for h, _ in seen if h.get("webhook-id") == headers.get("webhook-id")]
            return 500 if len(same) == 1 else 204

        return cls(policy)

    def of(self, job_id: str) -> list[tuple[dict[str, str], bytes]]:
        """The deliveries about one job."""
        with self.lock:
            return [d for d in self.deliveries if d[0].get("webhook-id", "").startswith(job_id)]

    def close(self) -> None:
        self.server.shutdown()
        self.server.server_close()
