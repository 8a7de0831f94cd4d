"""Typed dependencies for route handlers (``Annotated`` aliases)."""

from __future__ import annotations

from typing import Annotated

from fastapi import Depends, Request

from service.errors import ServiceError
from service.registry import Registry
from service.settings import Settings
from service.state import ServiceState


def get_state(request: Request) -> ServiceState:
    return request.app.state.service


def get_registry(request: Request) -> Registry:
    state: ServiceState = request.app.state.service
    if state.registry is None:
        raise ServiceError("not_ready", "the models are still loading; retry shortly")
    return state.registry


def get_app_settings(request: Request) -> Settings:
    return request.app.state.service.settings


StateDep = Annotated[ServiceState, Depends(get_state)]
RegistryDep = Annotated[Registry, Depends(get_registry)]
SettingsDep = Annotated[Settings, Depends(get_app_settings)]
