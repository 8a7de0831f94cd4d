"""Typed dependencies for route handlers (``Annotated`` aliases)."""

from __future__ import annotations

from typing import Annotated

from fastapi import Depends, Request

from service.errors import ServiceError
from service.registry import Registry
from service.state import ServiceState


def get_state(request: Request) -> ServiceState:
    return request.app.state.service


def get_registry(request: Request) -> Registry:
    state: ServiceState = request.app.state.service
    if state.registry is None:
        raise ServiceError("not_ready", "the models are still loading; retry shortly")
    return state.registry


StateDep = Annotated[ServiceState, Depends(get_state)]
RegistryDep = Annotated[Registry, Depends(get_registry)]
