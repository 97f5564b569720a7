"""Contract tests: schemathesis over the whole OpenAPI against a live server.

Every operation gets a bounded, seeded set of generated requests, valid and invalid;
every answer must conform: no 5xx, a documented status code and content type (every
error ``application/problem+json``), a body that matches the documented schema, the
headers it promises (a 405's ``Allow`` lists the path's methods), schema-valid
requests accepted, schema-violating ones rejected. Two passes: path ids as generated
(mostly unknown: 404s and 422s), and one world that exists (``contract``, room A), so
the operations behind the 404 run too.

One check is off: that every schema-valid request is accepted. What the worlds hold
decides there, and the generated requests create worlds too: a landmark must be in the
world, a goal must be one the sandbox allows, an eigenspace must be learned at this
image size, a learning job must fit the pixel cap, a name must not be taken (409). So do
rules JSON Schema cannot state (ids unique across a description's landmarks and
objects, as many intensities as ranges), and multipart parts without a file name
(form fields, which OpenAPI's ``format: binary`` does not tell from files). Every other
check runs on every operation.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
import schemathesis
from hypothesis import HealthCheck, settings
from schemathesis.checks import positive_data_acceptance
from schemathesis.config import SchemathesisConfig

from chizu.service.app import create_app
from chizu.service.settings import Settings
from tests.conftest import LiveServer

EXAMPLES = int(os.environ.get("CHIZU_CONTRACT_EXAMPLES", "15"))
WORLD = "contract"
# a 413 (a generated body past the 8 MiB limit) is a rejection too
CONFIG = """
[checks.negative_data_rejection]
expected-statuses = [400, 404, 405, 409, 413, 422]
"""


def load(parameters: str = "") -> schemathesis.BaseSchema:  # type: ignore[name-defined]
    spec = create_app(Settings(data_dir=Path(tempfile.mkdtemp()))).openapi()
    return schemathesis.openapi.from_dict(
        spec, config=SchemathesisConfig.from_str(CONFIG + parameters))


# live event streams last until the client leaves: no generated request ends them
# (their 404, 422 and 503 are tested in tests/service/test_events.py)
EVENTS = ["/worlds/{world}/events", "/jobs/events"]
schema = load().exclude(path=EVENTS)
# the second pass: every {world} is the existing one; deleting it would end the pass
on_a_world = load(f'[parameters]\n"path.world" = "{WORLD}"\n').exclude(
    method="DELETE").exclude(path=EVENTS)


@pytest.fixture(scope="module")
def live() -> Iterator[LiveServer]:
    env = {"CHIZU_MAX_LEARNING_PIXELS": "2000000", "CHIZU_REQUEST_BUDGET_S": "5",
           "CHIZU_JOB_BUDGET_S": "20"}
    with pytest.MonkeyPatch.context() as mp:  # the server's environment only
        for k, v in env.items():
            mp.setenv(k, v)
        srv = LiveServer(Path(tempfile.mkdtemp()) / "data", demo=True)
    r = httpx.post(srv.url + "/worlds", json={"name": WORLD, "template": "room_a"}, timeout=60)
    assert r.status_code == 201, r.text
    yield srv
    srv.stop()


SETTINGS = settings(max_examples=EXAMPLES, derandomize=True, deadline=None,
                    suppress_health_check=list(HealthCheck), database=None)


def check(case: schemathesis.Case, live: LiveServer) -> None:
    case.call_and_validate(base_url=live.url, timeout=60,
                           excluded_checks=[positive_data_acceptance])


@schema.parametrize()
@SETTINGS
def test_every_operation_keeps_its_contract(case: schemathesis.Case, live: LiveServer) -> None:
    check(case, live)


@on_a_world.parametrize()
@SETTINGS
def test_every_operation_on_an_existing_world_keeps_its_contract(
        case: schemathesis.Case, live: LiveServer) -> None:
    check(case, live)
