"""The form of a built-in style's id, ``builtin:NAME`` (docs/api-contract.md), apart from the code that serves
built-in styles, so that error messages can name one without importing it."""

from __future__ import annotations

PREFIX = "builtin:"
