"""Settings from the environment, and what importing the service does (nothing heavy)."""

from __future__ import annotations

import subprocess
import sys
from typing import Any

import pytest
from pydantic import ValidationError

from model.inference.bundle import DEFAULT_BUNDLE
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


def test_forwarded_headers_and_docs_settings(monkeypatch):
    for key in ("RSMT_FORWARDED_ALLOW_IPS", "RSMT_OPEN_DOCS_AND_METRICS"):
        monkeypatch.delenv(key, raising=False)
    s = Settings()
    assert s.forwarded_allow_ips == [] and s.open_docs_and_metrics is False  # no proxy trusted, docs behind keys
    monkeypatch.setenv("RSMT_FORWARDED_ALLOW_IPS", "10.0.0.1, 192.168.0.0/16")
    monkeypatch.setenv("RSMT_OPEN_DOCS_AND_METRICS", "true")
    s = Settings()
    assert s.forwarded_allow_ips == ["10.0.0.1", "192.168.0.0/16"] and s.open_docs_and_metrics is True


def test_import_builds_nothing_and_model_stays_free_of_web_code():
    code = ("import sys, service.app; "
            "assert 'uvicorn' not in sys.modules; "
            "import model.inference.engine; "
            "print('ok')")
    assert subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120).stdout.strip() == "ok"
    code = ("import sys, model.inference.engine, model.inference.bundle, model.motion.bvh; "
            "assert not [m for m in sys.modules if m.startswith(('fastapi', 'starlette', 'uvicorn'))]")
    assert subprocess.run([sys.executable, "-c", code], timeout=120).returncode == 0


def test_the_old_smoothing_names_still_work_with_a_warning(monkeypatch):
    monkeypatch.setenv("RSMT_OUTPUT_SMOOTHING", "0.2")
    with pytest.warns(DeprecationWarning) as caught:
        s = Settings(output_root_smoothing=0.1)
    said = [str(w.message) for w in caught]
    assert any("RSMT_OUTPUT_SMOOTHING" in m and "use smoothing (RSMT_SMOOTHING)" in m for m in said), said
    assert any("output_root_smoothing" in m and "use root_smoothing" in m for m in said), said
    assert (s.overrides().smoothing, s.overrides().root_smoothing) == (0.2, 0.1)
    assert s.overrides().given() == {"smoothing": 0.2, "root_smoothing": 0.1}


def test_output_settings_reach_the_engines(monkeypatch, tmp_path):
    from service.registry import load_registry

    monkeypatch.setenv("RSMT_SMOOTHING", "0.25")
    monkeypatch.setenv("RSMT_FOOT_LOCK", "true")
    s = Settings(models=DEFAULT_BUNDLE)
    assert (s.overrides().smoothing, s.overrides().foot_lock) == (0.25, True)
    engine = _engine_of(load_registry(s))
    assert engine.output.smoothing == 0.25 and engine.pipeline.step("foot_lock") is not None
    monkeypatch.setenv("RSMT_SMOOTHING", "1")
    with pytest.raises(ValidationError):
        Settings()
    monkeypatch.delenv("RSMT_SMOOTHING")
    monkeypatch.delenv("RSMT_FOOT_LOCK")
    engine = _engine_of(load_registry(Settings(models=DEFAULT_BUNDLE)))
    assert engine.output == engine.bundle.output  # unset: the bundle's own
    assert engine.inference.int8_lstm and engine.bundle.inference.int8_lstm  # the default bundle's setting
    monkeypatch.setenv("RSMT_INT8_LSTM", "false")
    assert not _engine_of(load_registry(Settings(models=DEFAULT_BUNDLE))).inference.int8_lstm
    # the default bundle's floor contact, and the setting that turns it off
    assert engine.pipeline.step("floor_contact") is not None
    monkeypatch.setenv("RSMT_FLOOR", "false")
    assert _engine_of(load_registry(Settings(models=DEFAULT_BUNDLE))).pipeline.step("floor_contact") is None
    # the foot plant, off in the default bundle, and the setting that turns it on
    assert engine.pipeline.step("foot_plant") is None
    monkeypatch.setenv("RSMT_FOOT_PLANT", "true")
    assert _engine_of(load_registry(Settings(models=DEFAULT_BUNDLE))).pipeline.step("foot_plant") is not None
    assert engine.inference.style_strength == 1.0
    monkeypatch.setenv("RSMT_STYLE_STRENGTH", "1.25")
    assert _engine_of(load_registry(Settings(models=DEFAULT_BUNDLE))).inference.style_strength == 1.25
    monkeypatch.setenv("RSMT_STYLE_STRENGTH", "5")
    with pytest.raises(ValidationError):
        Settings()


def test_eager_reaches_the_engines(monkeypatch):
    from service.registry import load_registry

    monkeypatch.delenv("RSMT_EAGER", raising=False)
    assert not _engine_of(load_registry(Settings(models=DEFAULT_BUNDLE))).step_fn.eager
    monkeypatch.setenv("RSMT_EAGER", "1")
    assert Settings().eager
    eager = _engine_of(load_registry(Settings(models=DEFAULT_BUNDLE)))
    assert eager.step_fn.eager and eager.output_fn.eager  # neither way is traced
    assert not eager.step_fn.trace_failed  # by choice, not because tracing failed


def _engine_of(registry):
    (model,) = list(registry)
    model.work.shutdown()
    model.step.shutdown()
    return model.engine


def test_the_settings_table_lists_every_declared_engine_setting():
    """docs/service.md's table has a row per declared setting (model.inference.declared_settings), its description
    opening with the declaration's help and range, and Settings has its RSMT_<NAME> field with that range."""
    from pathlib import Path

    from model.inference.declared_settings import SETTINGS

    doc = (Path(__file__).parents[2] / "docs" / "service.md").read_text()
    rows = {line.split(" | ")[0][3:-1]: line.split(" | ") for line in doc.splitlines() if line.startswith("| `RSMT_")}
    for s in SETTINGS:
        assert s.env in rows, f"docs/service.md's settings table has no row for {s.env}"
        opening = f"{s.help}, {s.range_words('`true` / `false`')}"
        assert rows[s.env][2].startswith(opening), f"{s.env}'s row should open with: {opening}"
        assert str(Settings.model_fields[s.name].description).startswith(s.help)
        if s.kind != "switch":
            below: dict[str, Any] = {s.name: s.low - 1}
            with pytest.raises(ValidationError):
                Settings(**below)
