"""The service harness knows its own server from another that took its port first.

:func:`service_harness.free_port` only finds a port that is free at that moment; on a machine where other
test runs start servers too, one of them may bind it before the service does. The service's own server
then fails to bind while the other answers its health checks (seen: a keyed service answered by a server
without keys, jobs queued on another server's broker), so the harness checks who listens.
"""

from __future__ import annotations

import http.server
import socket
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
import service_harness as h

pytestmark = pytest.mark.integration


class _Ok(http.server.BaseHTTPRequestHandler):
    def do_GET(self) -> None:
        self.send_response(200)
        self.end_headers()

    def log_message(self, *args: object) -> None:
        pass


@pytest.fixture
def foreign_server() -> Iterator[int]:
    """An HTTP server of this process (not of the service) answering 200 to everything."""
    server = http.server.HTTPServer(("127.0.0.1", 0), _Ok)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    yield int(server.server_address[1])
    server.shutdown()
    server.server_close()


def _service(tmp_path: Path, port: int, cmd: list[str]) -> h.LiveService:
    service = h.LiveService(f"http://127.0.0.1:{port}", tmp_path / "data", {})
    service.procs.append(h.Proc.start("api", cmd, env={"PATH": "/usr/bin:/bin"}, log_dir=tmp_path))
    return service


def _wait_listening(port: int, timeout_s: float = 20.0) -> None:
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            socket.create_connection(("127.0.0.1", port), timeout=1).close()
            return
        except OSError:
            assert time.monotonic() < deadline, f"nothing listens on {port}"
            time.sleep(0.05)


def test_a_port_answered_by_another_process_is_taken(tmp_path: Path, foreign_server: int) -> None:
    service = _service(tmp_path, foreign_server, [sys.executable, "-c", "import time; time.sleep(60)"])
    with pytest.raises(h.PortTakenError, match="another process answers"):
        service.wait_ready(timeout_s=20)
    assert not service.procs[0].alive()  # the service that lost its port is stopped


def test_the_services_own_listener_is_its_own(tmp_path: Path) -> None:
    port = h.free_port()
    server = [sys.executable, "-m", "http.server", str(port), "--bind", "127.0.0.1"]
    service = _service(tmp_path, port, ["/bin/sh", "-c", " ".join(server)])  # the listener is a child
    try:
        _wait_listening(port)
        service.check_listening()
    finally:
        service.stop()


def test_a_start_that_lost_its_port_is_tried_again_on_another() -> None:
    ports: list[int] = []

    def start(port: int) -> h.LiveService:
        ports.append(port)
        if len(ports) == 1:
            raise h.PortTakenError("taken")
        return h.LiveService(f"http://127.0.0.1:{port}", Path("/nonexistent"), {})

    service = h.on_a_port_of_its_own(start)
    assert len(ports) == 2
    assert service.base_url.endswith(f":{ports[1]}")
    service.client.close()


def test_a_failure_inside_logs_on_failure_carries_the_processes_logs(tmp_path: Path) -> None:
    proc = h.Proc.start(
        "talker",
        [sys.executable, "-c", "print('the worker said this')"],
        env={"PATH": "/usr/bin:/bin"},
        log_dir=tmp_path,
    )
    proc.popen.wait(timeout=30)
    service = h.LiveService(base_url="http://127.0.0.1:1", data_dir=tmp_path, env={}, procs=[proc])
    try:
        with pytest.raises(AssertionError) as caught, service.logs_on_failure():
            raise AssertionError("the session never got its ready message")
    finally:
        service.client.close()
    assert any("--- talker ---" in note and "the worker said this" in note for note in caught.value.__notes__)
