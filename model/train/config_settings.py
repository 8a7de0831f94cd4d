"""One training setting changed from the command line: ``KEY=VALUE``, the key dotted as in a preset.

``sampler_stage.loop.iterations=200`` is ``{"sampler_stage": {"loop": {"iterations": 200}}}`` in a
preset file. The value is read with the type of the setting it names: numbers, ``true``/``false``,
``null`` where a setting may be unset, and lists as comma-separated items (``restart_at=8000,12000``).
"""

from __future__ import annotations

import dataclasses
import types
import typing
from typing import Any

from model.train.presets import deep_merge

_TRUE = ("true", "yes", "on", "1")
_FALSE = ("false", "no", "off", "0")
_NONE = ("null", "none")


def setting_changes(texts: list[str], config: type) -> dict[str, Any]:
    """The settings ``KEY=VALUE`` of ``texts`` as nested changes to the dataclass ``config`` (as in a preset).

    Raises ValueError naming the text when it has no ``=``, names no setting of ``config`` (listing
    the keys at that level) or holds a value that is not of the setting's type.
    """
    changes: dict[str, Any] = {}
    for text in texts:
        key, sep, value = text.partition("=")
        key = key.strip()
        if not sep or not key:
            raise ValueError(f"--set {text!r}: write KEY=VALUE, e.g. sampler_stage.loop.iterations=200")
        hint = _setting_type(key, config)
        try:
            parsed = _parse(value.strip(), hint)
        except ValueError as exc:
            raise ValueError(f"--set {text!r}: {exc}") from exc
        nested: dict[str, Any] = {}
        inner = nested
        *groups, last = key.split(".")
        for group in groups:
            inner = inner.setdefault(group, {})
        inner[last] = parsed
        changes = deep_merge(changes, nested, new_keys=True)
    return changes


def _setting_type(key: str, config: type) -> Any:
    """The type of the setting ``key`` (dotted) of the dataclass ``config``."""
    cls, where = config, ""
    parts = key.split(".")
    for i, part in enumerate(parts):
        hints = typing.get_type_hints(cls)
        names = [f.name for f in dataclasses.fields(cls)]
        if part not in names:
            at = f" in {where}" if where else ""
            raise ValueError(f"--set {key}: no setting {part!r}{at}; the settings there: {', '.join(names)}")
        hint = hints[part]
        where = f"{where}.{part}" if where else part
        nested = isinstance(hint, type) and dataclasses.is_dataclass(hint)
        if i == len(parts) - 1:
            if nested:
                inner = ", ".join(f"{where}.{f.name}" for f in dataclasses.fields(hint))
                raise ValueError(f"--set {key}: {where} is a group of settings; name one of them: {inner}")
            return hint
        if not nested:
            raise ValueError(f"--set {key}: {where} is a single setting, not a group of settings")
        cls = hint
    raise AssertionError("unreachable")  # a key has at least one part


def _parse(text: str, hint: Any) -> Any:
    """``text`` read as a value of the type ``hint``; ValueError when it is not one."""
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin in (typing.Union, types.UnionType):
        if type(None) in args and text.lower() in _NONE:
            return None
        errors = []
        for option in (a for a in args if a is not type(None)):
            try:
                return _parse(text, option)
            except ValueError as exc:
                errors.append(str(exc))
        raise ValueError(" or ".join(errors))
    if origin is tuple:
        items = [t.strip() for t in text.strip("[]()").split(",")] if text.strip("[]() ") else []
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_parse(t, args[0]) for t in items)
        if len(items) != len(args):
            raise ValueError(f"expected {len(args)} comma-separated values, got {len(items)}")
        return tuple(_parse(t, a) for t, a in zip(items, args))
    return _scalar(text, hint)


def _scalar(text: str, hint: Any) -> Any:
    if hint is bool:
        if text.lower() in _TRUE + _FALSE:
            return text.lower() in _TRUE
        raise ValueError(f"expected true or false, got {text!r}")
    if hint in (int, float):
        try:
            return hint(text)
        except ValueError:
            raise ValueError(f"expected {'a whole number' if hint is int else 'a number'}, got {text!r}") from None
    if hint is str:
        return text
    raise ValueError(f"a setting of type {hint} cannot be set from the command line")
