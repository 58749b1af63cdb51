"""Webhooks: a job's ``callback_url`` is told when the job ends, signed, with retries.

- **Allow-list.** The operator lists the hosts callbacks may go to (``EIGENSCOPE_CALLBACK_HOSTS``); any
  other URL is refused when the job is created (422) and again before each delivery, so the server cannot
  be made to send requests into networks the operator did not choose. Redirects are never followed.
- **Signature.** Deliveries follow the Standard Webhooks scheme: headers ``webhook-id`` (the same for every
  retry of one event), ``webhook-timestamp`` (Unix seconds) and ``webhook-signature``
  ``v1,<base64 HMAC-SHA256 of "{id}.{timestamp}.{body}">`` keyed by ``EIGENSCOPE_CALLBACK_SECRET`` (a
  ``whsec_<base64>`` secret is base64-decoded first, as the scheme's libraries do). Receivers check the
  signature and refuse stale timestamps.
- **Retries.** A delivery that does not get a 2xx answer is tried again after ``retry_base_s``, doubled
  each time up to ``retry_max_s`` (or the receiver's ``Retry-After``), ``max_attempts`` times in all; the
  job shows the callback's state. Deliveries are leased in the job store, so several API processes share
  the work without sending one event twice at once.

The body is ``{"type": "job.succeeded" | "job.failed" | "job.cancelled", "timestamp": ..., "data": <Job>}``.
"""

from __future__ import annotations

import base64
import binascii
import fnmatch
import hashlib
import hmac
import json
import logging
import threading
import time
from collections.abc import Callable
from datetime import UTC, datetime
from typing import Any
from urllib.parse import urlsplit

from service.errors import InvalidInputError
from service.settings import Settings
from service.store import JobRecord, Store

log = logging.getLogger(__name__)

#: How long a delivery may hold its lease before another process may retry it.
_LEASE_PAD_S = 30.0


def _host_port(url: str) -> tuple[str, int]:
    parts = urlsplit(url)
    if parts.scheme not in ("http", "https") or not parts.hostname:
        raise ValueError("not an http(s) URL with a host")
    if parts.username is not None or parts.password is not None:
        raise ValueError("credentials in the URL are not allowed; authenticate by the signature")
    port = parts.port  # raises ValueError for a bad port
    return parts.hostname.lower(), port if port is not None else (443 if parts.scheme == "https" else 80)


def allowed(url: str, hosts: str | None) -> bool:
    """Whether ``url`` names a host (and port) on the comma-separated allow-list ``hosts``."""
    if not hosts:
        return False
    try:
        host, port = _host_port(url)
    except ValueError:
        return False
    for entry in (e.strip().lower() for e in hosts.split(",")):
        if not entry:
            continue
        pattern, want_port = entry, None
        if entry.startswith("["):  # [::1]:8080
            pattern, _, rest = entry[1:].partition("]")
            want_port = rest[1:] if rest.startswith(":") else None
        elif entry.count(":") == 1:
            pattern, want_port = entry.split(":")
        if want_port is not None and want_port != str(port):
            continue
        if fnmatch.fnmatchcase(host, pattern) if "*" in pattern else host == pattern:
            return True
    return False


def check_callback_url(url: str, settings: Settings) -> None:
    """Refuse (422) a ``callback_url`` this server will not call."""
    loc = ["body", "callback_url"]
    if not settings.callback_hosts:
        raise InvalidInputError(
            "this server sends no callbacks (the operator has not set EIGENSCOPE_CALLBACK_HOSTS); poll the "
            "job instead, e.g. GET /v1/jobs/{id}?wait=60",
            code="callbacks-disabled",
            errors=[{"loc": loc, "msg": "callbacks are disabled", "type": "value_error"}],
        )
    try:
        _host_port(url)
    except ValueError as exc:
        raise InvalidInputError(
            f"callback_url {url!r} is not usable: {exc}",
            code="invalid-callback-url",
            errors=[{"loc": loc, "msg": str(exc), "type": "value_error"}],
        ) from None
    if not allowed(url, settings.callback_hosts):
        raise InvalidInputError(
            f"callback_url host {urlsplit(url).netloc!r} is not on this server's allow-list "
            "(EIGENSCOPE_CALLBACK_HOSTS); ask the operator to add it",
            code="callback-host-not-allowed",
            errors=[{"loc": loc, "msg": "host not allowed", "type": "value_error"}],
        )


def secret_key(secret: str) -> bytes:
    """The HMAC key of a secret: ``whsec_<base64>`` decoded, any other string as UTF-8."""
    if secret.startswith("whsec_"):
        try:
            return base64.b64decode(secret[len("whsec_") :], validate=True)
        except (binascii.Error, ValueError):
            pass
    return secret.encode()


def sign(secret: str, message_id: str, timestamp: int, body: bytes) -> str:
    """The ``webhook-signature`` header value of a delivery."""
    signed = f"{message_id}.{timestamp}.".encode() + body
    digest = hmac.new(secret_key(secret), signed, hashlib.sha256).digest()
    return "v1," + base64.b64encode(digest).decode()


def verify(secret: str, headers: dict[str, str], body: bytes, *, tolerance_s: float = 300.0) -> bool:
    """Check a delivery's signature and timestamp as a receiver would (any ``v1`` signature may match)."""
    lower = {k.lower(): v for k, v in headers.items()}
    try:
        timestamp = int(lower["webhook-timestamp"])
        message_id = lower["webhook-id"]
        given = lower["webhook-signature"].split()
    except (KeyError, ValueError):
        return False
    if abs(time.time() - timestamp) > tolerance_s:
        return False
    expected = sign(secret, message_id, timestamp, body)
    return any(hmac.compare_digest(expected, candidate) for candidate in given)


def event_body(status: str, job: dict[str, Any]) -> bytes:
    """The JSON body announcing that a job (``job``: its API representation) ended with ``status``."""
    doc = {"type": f"job.{status}", "timestamp": datetime.now(UTC).isoformat(), "data": job}
    return json.dumps(doc, separators=(",", ":"), default=str).encode()


def retry_delay(attempts: int, settings: Settings, retry_after: str | None = None) -> float:
    """Seconds before the next try after ``attempts`` failed ones (the receiver's Retry-After, if longer)."""
    delay = min(settings.callback_retry_base_s * 2.0 ** max(attempts - 1, 0), settings.callback_retry_max_s)
    if retry_after is not None and retry_after.strip().isdigit():
        delay = max(delay, min(float(retry_after), settings.callback_retry_max_s))
    return float(delay)


class Dispatcher:
    """Delivers due callbacks from a background thread of the API process."""

    def __init__(
        self, store: Store, settings: Settings, render: Callable[[JobRecord], dict[str, Any]]
    ) -> None:
        self.store = store
        self.settings = settings
        self.render = render
        self.delivered = 0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        self._stop.clear()
        self._thread = threading.Thread(target=self._loop, name="eigenscope-webhooks", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=self.settings.callback_timeout_s + 5)
            self._thread = None

    def _loop(self) -> None:
        import httpx

        with httpx.Client(follow_redirects=False, timeout=self.settings.callback_timeout_s) as client:
            while not self._stop.is_set():
                try:
                    jobs = self.store.claim_due_callbacks(
                        limit=16, lease_s=self.settings.callback_timeout_s + _LEASE_PAD_S
                    )
                except Exception as exc:  # the database blinked: the next pass tries again
                    log.warning("webhooks: cannot read due callbacks: %s", exc)
                    jobs = []
                for job in jobs:
                    if self._stop.is_set():
                        return
                    try:
                        self.deliver(client, job)
                    except Exception:
                        log.warning("webhooks: delivering job %s's callback failed", job.id, exc_info=True)
                if not jobs:
                    self._stop.wait(self.settings.callback_poll_interval_s)

    def deliver(self, client: Any, job: JobRecord) -> bool:
        """One attempt for ``job`` (already leased); records the outcome. True when delivered."""
        import httpx

        settings = self.settings
        url = job.callback_url
        assert url is not None
        if not allowed(url, settings.callback_hosts) or not settings.callback_secret:
            self.store.record_callback(
                job.id, status="failed", next_at=None, error="host no longer on the allow-list"
            )
            log.warning("job %s: callback to %s dropped: its host is no longer allowed", job.id, url)
            return False
        body = event_body(job.status, self.render(job))
        message_id = f"{job.id}.{job.status}"
        timestamp = int(time.time())
        headers = {
            "content-type": "application/json",
            "user-agent": "eigenscope-webhooks",
            "webhook-id": message_id,
            "webhook-timestamp": str(timestamp),
            "webhook-signature": sign(settings.callback_secret, message_id, timestamp, body),
        }
        error: str
        retry_after = None
        try:
            response = client.post(url, content=body, headers=headers)
            if 200 <= response.status_code < 300:
                self.store.record_callback(job.id, status="delivered", next_at=None, error=None)
                self.delivered += 1
                log.info("job %s: callback delivered to %s (attempt %d)", job.id, url, job.callback_attempts)
                return True
            error = f"HTTP {response.status_code}"
            retry_after = response.headers.get("retry-after")
        except httpx.HTTPError as exc:
            error = f"{type(exc).__name__}: {exc}"[:300]
        if job.callback_attempts >= settings.callback_max_attempts:
            self.store.record_callback(job.id, status="failed", next_at=None, error=error)
            log.warning(
                "job %s: callback to %s failed %d times (%s); giving up",
                job.id,
                url,
                job.callback_attempts,
                error,
            )
            return False
        delay = retry_delay(job.callback_attempts, settings, retry_after)
        self.store.record_callback(job.id, status="pending", next_at=time.time() + delay, error=error)
        log.info("job %s: callback to %s failed (%s); retry in %.1f s", job.id, url, error, delay)
        return False
