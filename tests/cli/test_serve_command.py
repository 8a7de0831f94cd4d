"""``rsmt serve``'s choices that need no server: the log format and the address it announces.
(The announcement itself is tested through a real server in tests/service/test_lifecycle.py.)"""

from __future__ import annotations

import io
import sys

import pytest

from rsmt_cli.serve_commands import choose_log_format, public_url
from service.settings import Settings


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_log_format_text_on_a_terminal_json_otherwise(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("RSMT_LOG_FORMAT", raising=False)
    monkeypatch.setattr(sys, "stderr", _Terminal())
    assert choose_log_format(None, Settings()) == "text"
    assert choose_log_format("json", Settings()) == "json"  # the option wins
    monkeypatch.setenv("RSMT_LOG_FORMAT", "json")
    assert choose_log_format(None, Settings()) == "json"  # so does the setting, when given
    monkeypatch.setattr(sys, "stderr", io.StringIO())
    monkeypatch.delenv("RSMT_LOG_FORMAT")
    assert choose_log_format(None, Settings()) == "json"
    monkeypatch.setenv("RSMT_LOG_FORMAT", "text")
    assert choose_log_format(None, Settings()) == "text"


@pytest.mark.parametrize(("host", "url"), [
    ("127.0.0.1", "http://127.0.0.1:8000"),
    ("0.0.0.0", "http://127.0.0.1:8000"),
    ("::", "http://[::1]:8000"),
    ("::1", "http://[::1]:8000"),
    ("example.internal", "http://example.internal:8000"),
])
def test_public_url(host: str, url: str) -> None:
    assert public_url(host, 8000) == url
