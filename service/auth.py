"""API keys and tenants.

Keys come from ``EIGENSCOPE_API_KEYS`` (comma-separated) and/or ``EIGENSCOPE_API_KEYS_FILE`` (one a line,
either the key or ``sha256:<hex digest of the key>``). Only SHA-256 digests are kept in memory; a
presented key is hashed and looked up. Each key is its own tenant: the tenant id is derived from the
digest, so it never reveals the key and is stable across restarts.

With no key configured the service is open and every request belongs to the tenant ``""`` (the app logs
a warning at start).

A client (IP address; behind ``EIGENSCOPE_TRUSTED_PROXIES``, the address they forward) that presents
wrong keys more than ``EIGENSCOPE_AUTH_FAILURES_PER_WINDOW`` times in ``EIGENSCOPE_AUTH_FAILURE_WINDOW_S``,
over HTTP or a stream's WebSocket alike (:func:`authenticate`), is answered 429 with ``Retry-After``
until the window has passed, whatever key it sends meanwhile (a guess that happens to be right tells it
nothing) -- but a key that authenticated from that address before keeps working
(:class:`FailedAuthLimiter`). ``eigenscope serve`` hands its API process the keys' digests in a file
(:func:`write_digest_file`), never the keys.
"""

from __future__ import annotations

import hashlib
import hmac
import math
import os
import re
import tempfile
import threading
import time
from collections import deque
from dataclasses import dataclass
from pathlib import Path

from starlette.requests import HTTPConnection

from backend.errors import QuotaExceededError, UnauthorizedError
from backend.settings import Settings

#: Tenant of every request when the service runs without keys.
OPEN_TENANT = ""

_DIGEST = re.compile(r"^sha256:([0-9a-fA-F]{64})$")


#: Shortest key accepted in the configuration (a key is a password: make it long and random).
MIN_KEY_LENGTH = 16


class KeyConfigError(ValueError):
    """A configured key is too short, or the keys file cannot be read or holds a malformed line."""


def key_digest(key: str) -> str:
    """The hex SHA-256 of an API key (what a keys file may hold instead of the key)."""
    return hashlib.sha256(key.encode()).hexdigest()


def tenant_of_digest(digest: str) -> str:
    """The tenant id of a key with this digest: ``k`` and 23 hex digits of a second hash."""
    return "k" + hashlib.sha256(("eigenscope-tenant:" + digest).encode()).hexdigest()[:23]


@dataclass(frozen=True)
class KeyRing:
    """The digests of the configured keys, each mapped to its tenant."""

    tenants: dict[str, str]

    @property
    def enabled(self) -> bool:
        return bool(self.tenants)

    @classmethod
    def from_settings(cls, settings: Settings) -> KeyRing:
        digests: list[str] = []
        if settings.api_keys:
            for key in (k.strip() for k in settings.api_keys.split(",")):
                if key:
                    digests.append(key_digest(_checked(key, "EIGENSCOPE_API_KEYS")))
        if settings.api_keys_file is not None:
            digests += _read_keys_file(settings.api_keys_file)
        return cls({d: tenant_of_digest(d) for d in digests})

    def tenant(self, authorization: str | None) -> str:
        """The tenant of an ``Authorization`` header value; raises :class:`UnauthorizedError`."""
        if not self.enabled:
            return OPEN_TENANT
        if not authorization:
            raise UnauthorizedError(
                "this server needs an API key: send `Authorization: Bearer <key>`", code="missing-api-key"
            )
        scheme, _, key = authorization.strip().partition(" ")
        key = key.strip()
        if scheme.lower() != "bearer" or not key:
            raise UnauthorizedError(
                "send the API key as `Authorization: Bearer <key>`", code="invalid-authorization"
            )
        digest = key_digest(key)
        for known, tenant in self.tenants.items():
            if hmac.compare_digest(known, digest):
                return tenant
        raise UnauthorizedError("the API key is not valid", code="invalid-api-key")


def _read_keys_file(path: Path) -> list[str]:
    try:
        lines = path.read_text().splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise KeyConfigError(f"EIGENSCOPE_API_KEYS_FILE {path}: cannot read it ({exc})") from exc
    digests = []
    for number, raw in enumerate(lines, start=1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        match = _DIGEST.match(line)
        if match:
            digests.append(match.group(1).lower())
        elif line.startswith("sha256:") or any(c.isspace() for c in line):
            raise KeyConfigError(
                f"EIGENSCOPE_API_KEYS_FILE {path}, line {number}: expected a key or sha256:<64 hex digits>"
            )
        else:
            digests.append(key_digest(_checked(line, f"EIGENSCOPE_API_KEYS_FILE {path}, line {number}")))
    return digests


def _checked(key: str, where: str) -> str:
    if len(key) < MIN_KEY_LENGTH:
        raise KeyConfigError(
            f"{where}: a key of {len(key)} characters is too short; use at least {MIN_KEY_LENGTH} random "
            "characters (e.g. `python -c 'import secrets; print(secrets.token_urlsafe(32))'`)"
        )
    return key


def write_digest_file(ring: KeyRing, folder: Path) -> Path:
    """Write the ring's digests, one ``sha256:<hex>`` a line, to a new private file in ``folder``.

    For child processes: they read ``EIGENSCOPE_API_KEYS_FILE`` and never see a plain key.
    """
    folder.mkdir(parents=True, exist_ok=True)
    fd, name = tempfile.mkstemp(prefix=".api-key-digests-", dir=folder)
    with os.fdopen(fd, "w", encoding="ascii") as fh:  # mkstemp: mode 0600
        fh.write("# digests of the API keys, written by eigenscope serve for its processes\n")
        fh.writelines(f"sha256:{digest}\n" for digest in ring.tenants)
    return Path(name)


def check_metrics_token(token: str | None, keys_enabled: bool, authorization: str | None) -> None:
    """Raise :class:`UnauthorizedError` unless ``/metrics`` may be read with this ``Authorization``.

    With a token set it must be presented as ``Bearer <token>``; without one, ``/metrics`` is open on a
    server that runs open and refused on one with API keys (its counts span every tenant).
    """
    if token is None:
        if keys_enabled:
            raise UnauthorizedError(
                "/metrics spans every key's jobs: set EIGENSCOPE_METRICS_TOKEN and scrape with "
                "`Authorization: Bearer <token>`",
                code="metrics-token-required",
            )
        return
    scheme, _, given = (authorization or "").strip().partition(" ")
    if scheme.lower() != "bearer" or not hmac.compare_digest(given.strip().encode(), token.encode()):
        raise UnauthorizedError(
            "send the metrics token as `Authorization: Bearer <token>`", code="invalid-token"
        )


class FailedAuthLimiter:
    """Counts wrong credentials per client (address) and refuses (429) a client past its limit.

    A client past its limit is refused whatever key it sends (a guess that happens to be right must look
    like any other), with one exception: a key that authenticated from this very address before, within
    ``known_s``, keeps working from it (the other robots behind one NAT or proxy address are not locked
    out by one that sends wrong keys). A key first seen from a throttled address is refused until the
    window has passed, and is not remembered as known.
    """

    #: Clients (and client-key pairs) remembered at most (the oldest are forgotten first).
    MAX_CLIENTS = 10_000

    def __init__(self, limit: int, window_s: float, *, known_s: float = 0.0) -> None:
        self.limit = limit
        self.window_s = window_s
        self.known_s = known_s
        self._failures: dict[str, deque[float]] = {}
        self._known: dict[tuple[str, str], float] = {}
        self._lock = threading.Lock()

    def _wait_s(self, client: str, now: float) -> int | None:
        """Seconds until ``client`` may try again, None when it is not throttled (lock held)."""
        failures = self._failures.get(client)
        if failures is None:
            return None
        while failures and failures[0] <= now - self.window_s:
            failures.popleft()
        if len(failures) < self.limit:
            return None
        return max(1, math.ceil(failures[0] + self.window_s - now))

    def check(self, client: str) -> None:
        """Raise :class:`QuotaExceededError` (429) while ``client`` is over its limit."""
        with self._lock:
            wait = self._wait_s(client, time.monotonic())
        if wait is not None:
            raise _throttled(wait)

    def admit(self, client: str, tenant: str) -> None:
        """A valid key of ``tenant`` from ``client``: raise 429 while the client is throttled, unless the
        key is known from it; remember it as known when the client is not throttled."""
        now = time.monotonic()
        with self._lock:
            wait = self._wait_s(client, now)
            pair = (client, tenant)
            if wait is not None:
                seen = self._known.get(pair)
                if seen is None or now - seen > self.known_s:
                    raise _throttled(wait)
            if self.known_s > 0:
                self._known.pop(pair, None)
                self._known[pair] = now  # most recent last
                while len(self._known) > self.MAX_CLIENTS:
                    del self._known[next(iter(self._known))]

    def failed(self, client: str) -> None:
        """Count one wrong credential of ``client``."""
        with self._lock:
            failures = self._failures.pop(client, None) or deque()
            failures.append(time.monotonic())
            self._failures[client] = failures  # most recent last: the first ones are forgotten first
            while len(self._failures) > self.MAX_CLIENTS:
                del self._failures[next(iter(self._failures))]


def _throttled(wait_s: int) -> QuotaExceededError:
    return QuotaExceededError(
        f"too many requests with a wrong API key from this client; try again in {wait_s} s",
        code="too-many-failed-authentications",
        retry_after_s=wait_s,
    )


def client_address(connection: HTTPConnection) -> str:
    """The client's address: the peer's, or the one a trusted proxy forwarded (``eigenscope serve``
    lets uvicorn read ``X-Forwarded-For`` from ``EIGENSCOPE_TRUSTED_PROXIES`` only)."""
    return connection.client.host if connection.client is not None else ""


def authenticate(keys: KeyRing, limiter: FailedAuthLimiter, client: str, authorization: str | None) -> str:
    """The tenant of a request or WebSocket from ``client`` (its address, as the trusted proxies give
    it) with this ``Authorization``: the one path of both, throttled by one limiter.

    Raises :class:`UnauthorizedError` (401) for a missing or wrong key and :class:`QuotaExceededError`
    (429) while the client is throttled (see :class:`FailedAuthLimiter`). A missing key is not a guess
    and is not counted.
    """
    if not keys.enabled:
        return OPEN_TENANT
    try:
        tenant = keys.tenant(authorization)
    except UnauthorizedError as exc:
        limiter.check(client)  # a throttled client gets 429 whatever it sends
        if exc.code != "missing-api-key":  # a credential was presented, and it was wrong
            limiter.failed(client)
        raise
    limiter.admit(client, tenant)
    return tenant
