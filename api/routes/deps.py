"""Shared ``Annotated`` dependencies of the routers."""

from __future__ import annotations

from typing import Annotated

from fastapi import Depends

from api.context import AppContext, get_context

Ctx = Annotated[AppContext, Depends(get_context)]

__all__ = ["Ctx"]
