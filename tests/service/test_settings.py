"""Settings from the environment, and what importing the service does (nothing heavy)."""

from __future__ import annotations

import subprocess
import sys

import pytest
from pydantic import ValidationError

from model.bundle import DEFAULT_BUNDLE
from service.settings import Settings


def test_defaults(monkeypatch):
    for key in ("RSMT_MODELS", "RSMT_PORT", "RSMT_API_KEYS"):
        monkeypatch.delenv(key, raising=False)
    s = Settings()
    assert (s.host, s.port, s.models) == ("127.0.0.1", 8000, DEFAULT_BUNDLE)
    assert s.max_body_bytes == 1 << 20 and s.ws_max_message_bytes == 64 << 10
    assert not s.auth_enabled and s.rate_limit_per_s == 0 and s.log_level == "warning" and s.log_format == "json"


def test_environment(monkeypatch, tmp_path):
    monkeypatch.setenv("RSMT_PORT", "9001")
    monkeypatch.setenv("RSMT_MODELS", str(tmp_path))
    monkeypatch.setenv("RSMT_API_KEYS", "aaaaaaaaaaaaaaaa1, bbbbbbbbbbbbbbbb2")
    s = Settings()
    assert s.port == 9001 and s.models == tmp_path and s.api_keys == ["aaaaaaaaaaaaaaaa1", "bbbbbbbbbbbbbbbb2"]
    monkeypatch.setenv("RSMT_API_KEYS", '["cccccccccccccccc3"]')
    assert Settings().api_keys == ["cccccccccccccccc3"]
    monkeypatch.setenv("RSMT_API_KEYS", "short")
    with pytest.raises(ValidationError, match="16 characters"):
        Settings()


def test_import_builds_nothing_and_model_stays_free_of_web_code():
    code = ("import sys, service.app; "
            "assert 'uvicorn' not in sys.modules; "
            "import model.engine; "
            "print('ok')")
    assert subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120).stdout.strip() == "ok"
    code = ("import sys, model.engine, model.bundle, model.bvh; "
            "assert not [m for m in sys.modules if m.startswith(('fastapi', 'starlette', 'uvicorn'))]")
    assert subprocess.run([sys.executable, "-c", code], timeout=120).returncode == 0
