"""``Annotated`` dependencies of the routes: the app's context and its parts."""

from __future__ import annotations

from typing import Annotated

from fastapi import Depends, Request

from service.context import ServiceContext
from service.settings import Settings
from service.storage import Storage
from service.store import Store


def get_context(request: Request) -> ServiceContext:
    ctx = request.app.state.ctx
    assert isinstance(ctx, ServiceContext)
    return ctx


def get_settings(request: Request) -> Settings:
    return get_context(request).settings


def get_store(request: Request) -> Store:
    return get_context(request).store


def get_storage(request: Request) -> Storage:
    return get_context(request).storage


ContextDep = Annotated[ServiceContext, Depends(get_context)]
SettingsDep = Annotated[Settings, Depends(get_settings)]
StoreDep = Annotated[Store, Depends(get_store)]
StorageDep = Annotated[Storage, Depends(get_storage)]
