"""The errors in the OpenAPI document (``server.core.errors``): every operation lists what it may answer
besides its result, each with the one error body's schema (``Problem``), derived from the error classes;
and what the API answers is what the document says."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import pytest
from fastapi.testclient import TestClient

from server.app import create_app
from tests.support.api import OBSERVER, OP, offline_settings

PROBLEM = {"$ref": "#/components/schemas/Problem"}


@pytest.fixture(scope="module")
def client(tmp_path_factory: pytest.TempPathFactory) -> Iterator[TestClient]:
    with TestClient(create_app(offline_settings(tmp_path_factory.mktemp("openapi")))) as c:
        yield c


@pytest.fixture(scope="module")
def document(client: TestClient) -> dict[str, Any]:
    return client.get("/openapi.json").json()


def errors_of(document: dict[str, Any], method: str, path: str) -> set[int]:
    answers = document["paths"][path][method]["responses"]
    return {int(status) for status in answers if int(status) >= 400}


def test_every_error_answer_is_documented_with_the_problem_schema(document: dict[str, Any]) -> None:
    operations = [op for item in document["paths"].values() for op in item.values()]
    assert len(operations) > 40
    for op in operations:
        for status, answer in op["responses"].items():
            if int(status) >= 400:
                assert answer["content"]["application/json"]["schema"] == PROBLEM, (op["operationId"], status)
                assert answer["description"], (op["operationId"], status)
    schemas = document["components"]["schemas"]
    assert {"detail", "field", "errors"} <= set(schemas["Problem"]["properties"])
    assert "HTTPValidationError" not in schemas  # FastAPI's 422 body, which this server never answers


def test_each_operation_lists_the_errors_its_route_and_its_token_check_raise(
    document: dict[str, Any],
) -> None:
    assert errors_of(document, "post", "/api/v1/vehicles") == {401, 403, 409, 422, 429, 503}
    assert errors_of(document, "get", "/api/v1/vehicles/{vehicle_id}") == {401, 404, 422, 429, 503}
    assert errors_of(document, "get", "/api/v1/operators") == {401, 403, 429, 503}  # an operator's token
    assert errors_of(document, "get", "/api/v1/health") == {503}  # no token, nothing to refuse


def test_what_the_api_answers_is_what_the_document_says(client: TestClient, document: dict[str, Any]) -> None:
    problem = document["components"]["schemas"]["Problem"]
    vehicle = {"name": "rov1", "address": 2}
    created = client.post("/api/v1/vehicles", json=vehicle, headers=OP)
    assert created.status_code == 201
    answers = [
        ("post", "/api/v1/vehicles", client.post("/api/v1/vehicles", json=vehicle)),  # no token
        ("post", "/api/v1/vehicles", client.post("/api/v1/vehicles", json=vehicle, headers=OBSERVER)),
        ("post", "/api/v1/vehicles", client.post("/api/v1/vehicles", json=vehicle, headers=OP)),  # taken
        ("post", "/api/v1/vehicles", client.post("/api/v1/vehicles", json={"name": 3}, headers=OP)),
        ("get", "/api/v1/vehicles/{vehicle_id}", client.get("/api/v1/vehicles/999", headers=OBSERVER)),
    ]
    assert [response.status_code for _, _, response in answers] == [401, 403, 409, 422, 404]
    for method, path, response in answers:
        assert response.status_code in errors_of(document, method, path)
        body = response.json()
        assert set(body) <= set(problem["properties"]) and set(problem["required"]) <= set(body), body
        assert isinstance(body["detail"], str) and (body["field"] is None or isinstance(body["field"], str))
