"""The same service tests on both backends (RSMT_BACKEND=torch and onnxruntime): HTTP transitions, styles, errors,
and streams with a retarget, a style switch, many characters and exact arrival, every output step switched on.

The tests are the existing ones of test_http.py and test_stream.py, collected again here against a server per
backend (the module's ``server`` fixture, which the ``client`` of tests/service/conftest.py then talks to);
their own modules run them on the default backend too.
"""

from __future__ import annotations

import httpx
import pytest

from model.export.backends import BACKENDS
from tests.service.routes import test_http
from tests.service.routes.test_http import (  # noqa: F401  (collected again, on this module's servers)
    style_id,
    test_bad_requests,
    test_inline_style_and_json_poses,
    test_model_description,
    test_same_seed_same_frames,
    test_transition_json,
)
from tests.service.routes.test_stream import (  # noqa: F401  (collected again, on this module's servers)
    styles,
    test_exact_arrival,
    test_frames_in_order_then_end,
    test_many_characters_one_connection,
    test_retarget_changes_where_it_arrives,
    test_stream_equals_http_transition,
    test_style_switch,
)
from tests.service.server import Server

pytestmark = pytest.mark.slow  # a server per backend

# Every output step on, so the onnxruntime server runs its whole output graph (the test bundle's own settings
# switch them off).
OUTPUT_STEPS = {"RSMT_OUTPUT_SMOOTHING": "0.3", "RSMT_FOOT_LOCK": "true", "RSMT_FLOOR": "true", "RSMT_STEERING": "20",
                "RSMT_STRIDE_WARP": "1.0"}


@pytest.fixture(scope="module", params=BACKENDS)
def server(request: pytest.FixtureRequest, bundle_dir):
    srv = Server(bundle_dir, env={"RSMT_BACKEND": request.param, "RSMT_IDLE_TIMEOUT_S": "5",
                                  "RSMT_MAX_CHARACTERS_PER_CONNECTION": "16", **OUTPUT_STEPS}).start(timeout_s=180.0)
    yield srv
    srv.stop()


def test_the_server_runs_the_backend_it_was_given(server):
    assert server.env["RSMT_BACKEND"] in BACKENDS
    r = httpx.post(server.url + "/v1/transition", json={**test_http.transition_body(frames=12)}, timeout=60)
    assert r.status_code == 200 and len(r.json()["frames"]) == 12


def test_the_service_default_is_the_engine_default_and_a_wrong_name_is_refused():
    from pydantic import ValidationError

    from model.export.backends import DEFAULT_BACKEND
    from service.settings import Settings

    assert Settings().backend == DEFAULT_BACKEND
    with pytest.raises(ValidationError, match="onnxruntime"):
        Settings(backend="tensorrt")
