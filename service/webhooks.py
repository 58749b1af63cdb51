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
  job shows the callback's state. Every failure of an attempt (an unreachable receiver, a URL httpx
  refuses, anything) is recorded and counted; the attempts never pass the maximum.
- **Concurrency.** Up to ``callback_concurrency`` deliveries run at once, ``callback_per_host`` at most
  to one host: a receiver that hangs delays only its own callbacks. Deliveries are leased in the job
  store (the lease outlasts any delivery and is renewed while it runs), so several API processes share
  the work without sending one attempt twice.

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

from backend.errors import InvalidInputError
from backend.settings import Settings
from backend.store import JobRecord, Store

log = logging.getLogger(__name__)

#: How long a delivery may hold its lease before another process may retry it.
_LEASE_PAD_S = 30.0


def parse_callback_url(url: str) -> Any:
    """``url`` parsed by httpx, the parser that delivers it (an ``httpx.URL``); ``ValueError`` saying why
    it is not usable: whitespace or control characters (which ``urlsplit`` would silently strip, and
    httpx refuses), no http(s) scheme or host, credentials, a port outside 1-65535."""
    import httpx

    bad = next((c for c in url if c.isspace() or ord(c) < 0x20 or ord(c) == 0x7F), None)
    if bad is not None:
        raise ValueError(f"it holds the character {bad!r}; whitespace and control characters are not allowed")
    try:
        parsed = httpx.URL(url)
    except httpx.InvalidURL as exc:
        raise ValueError(str(exc)) from None
    if parsed.scheme not in ("http", "https") or not parsed.host or "%" in parsed.host:
        raise ValueError("not an http(s) URL with a host")
    if parsed.userinfo:
        raise ValueError("credentials in the URL are not allowed; authenticate by the signature")
    if parsed.port is not None and not 1 <= parsed.port <= 65535:
        raise ValueError(f"port {parsed.port} is not between 1 and 65535")
    return parsed


def _host_key(url: str) -> str:
    """The host a callback goes to, for the per-host limit ("" for an unusable URL)."""
    try:
        return _host_port(url)[0]
    except ValueError:
        return ""


def _host_port(url: str) -> tuple[str, int]:
    parsed = parse_callback_url(url)
    port = parsed.port if parsed.port is not None else (443 if parsed.scheme == "https" else 80)
    return str(parsed.host).lower(), int(port)


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
            f"callback_url host {_host_port(url)[0]!r} is not on this server's allow-list "
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
    """Delivers due callbacks from background threads of the API process.

    Up to ``callback_concurrency`` deliveries run at once, at most ``callback_per_host`` of them to one
    host, so a receiver that hangs delays only its own callbacks. A delivery's lease (kept in the job
    store, renewed while it runs) outlasts it, so no other API process sends the same attempt again.
    """

    def __init__(
        self, store: Store, settings: Settings, render: Callable[[JobRecord], dict[str, Any]]
    ) -> None:
        self.store = store
        self.settings = settings
        self.render = render
        self.delivered = 0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._lock = threading.Lock()
        self._hosts: dict[str, int] = {}  # deliveries under way, per host
        self._running: set[str] = set()  # job ids being delivered

    @property
    def lease_s(self) -> float:
        """A delivery's lease: longer than connecting, sending and reading the answer's head, each
        within ``callback_timeout_s`` (and renewed every third of it while the delivery runs)."""
        return 4 * self.settings.callback_timeout_s + _LEASE_PAD_S

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
        from concurrent.futures import ThreadPoolExecutor

        import httpx

        workers = self.settings.callback_concurrency
        timeout = self.settings.callback_timeout_s
        limits = httpx.Limits(max_connections=workers, max_keepalive_connections=workers)
        pool = ThreadPoolExecutor(workers, thread_name_prefix="eigenscope-webhook")
        with httpx.Client(follow_redirects=False, timeout=timeout, limits=limits) as client:
            try:
                next_renewal = time.monotonic() + self.lease_s / 3
                while not self._stop.is_set():
                    try:
                        jobs = self._claim()
                    except Exception as exc:  # the database blinked: the next pass tries again
                        log.warning("webhooks: cannot read due callbacks: %s", exc)
                        jobs = []
                    for job in jobs:
                        pool.submit(self._run, client, job)
                    if time.monotonic() >= next_renewal:
                        next_renewal = time.monotonic() + self.lease_s / 3
                        self._renew_leases()
                    if not jobs:
                        self._stop.wait(self.settings.callback_poll_interval_s)
            finally:
                pool.shutdown(wait=False, cancel_futures=True)

    def _claim(self) -> list[JobRecord]:
        """Lease the due callbacks there is room for: free workers, and hosts under their limit."""
        settings = self.settings
        with self._lock:
            free = settings.callback_concurrency - len(self._running)
            hosts = dict(self._hosts)
        if free <= 0:
            return []
        claimed: list[JobRecord] = []
        for job_id, url in self.store.due_callbacks(limit=4 * settings.callback_concurrency):
            if len(claimed) >= free:
                break
            host = _host_key(url)
            if hosts.get(host, 0) >= settings.callback_per_host:
                continue
            job = self.store.claim_callback(
                job_id, lease_s=self.lease_s, max_attempts=settings.callback_max_attempts
            )
            if job is None:
                continue
            hosts[host] = hosts.get(host, 0) + 1
            with self._lock:
                self._hosts[host] = self._hosts.get(host, 0) + 1
                self._running.add(job.id)
            claimed.append(job)
        return claimed

    def _run(self, client: Any, job: JobRecord) -> None:
        try:
            if not self._stop.is_set():
                self.deliver(client, job)
        except Exception:
            log.warning("webhooks: delivering job %s's callback failed", job.id, exc_info=True)
        finally:
            host = _host_key(job.callback_url or "")
            with self._lock:
                self._running.discard(job.id)
                self._hosts[host] -= 1
                if not self._hosts[host]:
                    del self._hosts[host]

    def _renew_leases(self) -> None:
        with self._lock:
            running = list(self._running)
        for job_id in running:
            try:
                self.store.renew_callback_lease(job_id, lease_s=self.lease_s)
            except Exception as exc:
                log.warning("webhooks: cannot renew the lease of job %s's callback: %s", job_id, exc)

    @staticmethod
    def _post(client: Any, url: str, body: bytes, headers: dict[str, str]) -> tuple[int, str | None]:
        """POST and read the answer's status and ``Retry-After``, never its body."""
        with client.stream("POST", url, content=body, headers=headers) as response:
            return int(response.status_code), response.headers.get("retry-after")

    def deliver(self, client: Any, job: JobRecord) -> bool:
        """One attempt for ``job`` (already leased); records the outcome. True when delivered."""
        settings = self.settings
        url = job.callback_url
        assert url is not None
        try:
            parse_callback_url(url)
        except ValueError as exc:  # stored before the URLs were checked as they are now
            self.store.record_callback(
                job.id, status="failed", next_at=None, error=f"the callback URL is not usable: {exc}"
            )
            log.warning("job %s: callback dropped: its URL is not usable (%s)", job.id, exc)
            return False
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
            status, retry_after = self._post(client, url, body, headers)
            if 200 <= status < 300:
                self.store.record_callback(job.id, status="delivered", next_at=None, error=None)
                self.delivered += 1
                log.info("job %s: callback delivered to %s (attempt %d)", job.id, url, job.callback_attempts)
                return True
            error = f"HTTP {status}"
        except Exception as exc:  # every failure of the attempt is recorded and counted against the rest
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
