"""API keys and tenants.

Keys come from ``EIGENSCOPE_API_KEYS`` (comma-separated) and/or ``EIGENSCOPE_API_KEYS_FILE`` (one a line,
either the key or ``sha256:<hex digest of the key>``). Only SHA-256 digests are kept in memory; a
presented key is hashed and looked up. Each key is its own tenant: the tenant id is derived from the
digest, so it never reveals the key and is stable across restarts.

With no key configured the service is open and every request belongs to the tenant ``""`` (the app logs
a warning at start).
"""

from __future__ import annotations

import hashlib
import hmac
import re
from dataclasses import dataclass
from pathlib import Path

from service.errors import UnauthorizedError
from service.settings import Settings

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
