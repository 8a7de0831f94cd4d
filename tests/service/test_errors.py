"""The engine's refusals reach clients as the contract's codes and HTTP statuses, with the engine's message."""

from __future__ import annotations

import pytest

from model.inference.errors import EngineError, FramesOutOfRange, SkeletonMismatch, TooFewFrames, TooManyFrames
from service.errors import STATUS, ServiceError, from_engine


@pytest.mark.parametrize(("error", "code", "status"), [
    (SkeletonMismatch, "skeleton_mismatch", 422),
    (TooFewFrames, "too_few_frames", 422),
    (TooManyFrames, "too_many_frames", 422),
    (FramesOutOfRange, "validation_error", 422),
    (EngineError, "validation_error", 422),
])
def test_engine_errors_map_to_contract_codes(error, code, status):
    out = from_engine(error("what went wrong, and what is accepted"))
    assert isinstance(out, ServiceError)
    assert (out.code, out.status, out.message) == (code, status, "what went wrong, and what is accepted")


def test_every_code_has_a_status():
    with pytest.raises(ValueError, match="unknown error code"):
        ServiceError("no_such_code", "x")
    assert all(400 <= s < 600 for s in STATUS.values())
