"""The OpenAPI document says what the API really does: each operation lists the error codes it can
answer (and no others), every 422 has the shape service.app writes, downloads name their media
types, and the bearer scheme gives /docs its Authorize button."""

from __future__ import annotations

from fastapi import FastAPI
from fastapi.openapi.utils import get_openapi

from service.schemas import ErrorOut, ValidationErrorOut

WHY = {
    401: "Missing or invalid API key (only when keys are configured).",
    404: "No such id among your own meshes/jobs.",
    409: "Conflicts with the resource's state (e.g. the job has not succeeded, or has ended).",
    413: "Request body or mesh too large, or your storage quota is used up.",
    422: "Invalid request: `detail` says what, `field` names the parameter.",
    429: "Too many queued or running jobs (see Retry-After).",
    503: "The job queue (broker) is unreachable; nothing was queued (see Retry-After).",
}


def errors(*codes: int) -> dict:
    """`responses=` entries for these error codes."""
    return {
        code: {"model": ValidationErrorOut if code == 422 else ErrorOut, "description": WHY[code]}
        for code in codes
    }


def binary(media: str, doc: str) -> dict:
    """A 200 response carrying a file of media type `media`."""
    return {200: {"description": doc, "content": {media: {"schema": {"type": "string", "format": "binary"}}}}}


def _can_fail_validation(op: dict) -> bool:
    """FastAPI documents a 422 for any operation with parameters; only a request body, a query,
    header or cookie parameter, or a constrained path parameter can really fail validation."""
    if "requestBody" in op:
        return True
    for param in op.get("parameters", []):
        plain = {k: v for k, v in param.get("schema", {}).items() if k not in ("title", "description")}
        if param.get("in") != "path" or plain != {"type": "string"}:
            return True
    return False


def install(app: FastAPI) -> None:
    """Replace app.openapi with the tidied document (built once)."""

    def openapi() -> dict:
        if app.openapi_schema:
            return app.openapi_schema
        doc = get_openapi(
            title=app.title, version=app.version, description=app.description, routes=app.routes
        )
        for ops in doc.get("paths", {}).values():
            for op in ops.values():
                responses = op.get("responses", {})
                if "422" in responses:
                    if not _can_fail_validation(op):
                        del responses["422"]
                    else:
                        responses["422"] = {
                            "description": WHY[422],
                            "content": {
                                "application/json": {
                                    "schema": {"$ref": "#/components/schemas/ValidationErrorOut"}
                                }
                            },
                        }
        schemas = doc.get("components", {}).get("schemas", {})
        text = str(doc.get("paths"))
        for name in ("HTTPValidationError", "ValidationError"):
            if f"/{name}'" not in text:
                schemas.pop(name, None)
        app.openapi_schema = doc
        return doc

    app.openapi = openapi
