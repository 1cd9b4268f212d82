"""The agglomeration models the library offers, with their cards."""

from __future__ import annotations

from fastapi import APIRouter

from service.schemas import ModelCard

router = APIRouter(prefix="/v1", tags=["models"])


@router.get("/models", response_model=list[ModelCard])
def list_models() -> list[dict]:
    """Name, dimension, modes, description and version of every agglomeration model."""
    from models import api

    return api.list_models()
