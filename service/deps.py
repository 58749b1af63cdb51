"""``Annotated`` dependencies of the routes: the app's context and its parts.

The context and tenant dependencies are ``async``: they only read memory, and a sync dependency would
cost a thread-pool hop on every request.
"""

from __future__ import annotations

from typing import Annotated

from fastapi import Depends, Header, Query, Request, Security
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from backend.settings import Settings
from backend.storage import Storage
from backend.store import Store
from service.auth import OPEN_TENANT, authenticate, client_address
from service.context import ServiceContext


async def get_context(request: Request) -> ServiceContext:
    return _context(request)


def _context(request: Request) -> ServiceContext:
    ctx = request.app.state.ctx
    assert isinstance(ctx, ServiceContext)
    return ctx


async def get_settings(request: Request) -> Settings:
    return _context(request).settings


async def get_store(request: Request) -> Store:
    return _context(request).store


async def get_storage(request: Request) -> Storage:
    return _context(request).storage


#: Declares the bearer scheme in the OpenAPI document; the key ring does the checking (401 problem).
_bearer = HTTPBearer(
    auto_error=False,
    scheme_name="ApiKey",
    description="`Authorization: Bearer <API key>`, when the server is configured with keys.",
)


async def get_tenant(
    request: Request,
    credentials: Annotated[HTTPAuthorizationCredentials | None, Security(_bearer)],
) -> str:
    """The tenant (API key) of the request; 401 problem when keys are configured and none valid is sent,
    429 once the client has sent too many wrong ones (see :class:`service.auth.FailedAuthLimiter`)."""
    ctx = _context(request)
    if not ctx.keys.enabled:
        return OPEN_TENANT
    return authenticate(
        ctx.keys, ctx.auth_limiter, client_address(request), request.headers.get("authorization")
    )


ContextDep = Annotated[ServiceContext, Depends(get_context)]
SettingsDep = Annotated[Settings, Depends(get_settings)]
StoreDep = Annotated[Store, Depends(get_store)]
StorageDep = Annotated[Storage, Depends(get_storage)]
#: The caller's tenant id ("" when the service runs without keys).
TenantDep = Annotated[str, Depends(get_tenant)]

#: The ``Idempotency-Key`` header that makes a retried POST safe (None when not sent).
IdempotencyKey = Annotated[
    str | None,
    Header(
        alias="Idempotency-Key",
        min_length=1,
        max_length=255,
        description="Client-chosen key that makes retries of this request safe.",
    ),
]

#: Paging of the list routes: the page size, and the ``next_cursor`` of the previous page.
PageSize = Annotated[int, Query(ge=1, le=100, description="Page size.")]
Cursor = Annotated[str | None, Query(max_length=256, description="`next_cursor` of the previous page.")]
