"""The request fields of the contract, and the JSON keys each client writes, read from their source.

The contract's fields come from the server itself: the JSON request bodies of ``app.openapi()`` (built from
``service/app.py``) and the JSON schema of the stream's client messages (``service.schemas.CLIENT_MESSAGE``, the
pydantic models ``service/sessions/protocol.py`` reads), each nested object (a ``Motion``'s ``BvhMotion`` and
``PoseMotion``) as a shape of its own.

A client's keys are read from the functions that build each body: in Python the string constants of those
functions (``body["seed"] = ...``, ``{"type": "start", ...}``), in C# and C++ the keys their JSON text writes
(``\\"seed\\":``).
"""

from __future__ import annotations

import ast
import re
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[2]


# ---------------------------------------------------------------------- the contract

def _resolve(schema: Mapping[str, Any], components: Mapping[str, Any]) -> tuple[str | None, Mapping[str, Any]]:
    ref = schema.get("$ref")
    if isinstance(ref, str):
        name = ref.rsplit("/", 1)[-1]
        return name, components[name]
    return None, schema


def _nested_refs(schema: Any) -> Iterable[str]:
    """The component names referenced anywhere inside ``schema``."""
    if isinstance(schema, Mapping):
        ref = schema.get("$ref")
        if isinstance(ref, str):
            yield ref.rsplit("/", 1)[-1]
        for value in schema.values():
            yield from _nested_refs(value)
    elif isinstance(schema, list):
        for value in schema:
            yield from _nested_refs(value)


def _shapes(bodies: Mapping[str, Mapping[str, Any]], components: Mapping[str, Any]) -> dict[str, set[str]]:
    """Each body's top-level fields, plus every object schema its fields reference (by component name)."""
    out: dict[str, set[str]] = {}
    todo: list[str] = []
    for operation, body in bodies.items():
        _, schema = _resolve(body, components)
        out[operation] = set(schema.get("properties", {}))
        todo.extend(_nested_refs(schema.get("properties", {})))
    while todo:
        name = todo.pop()
        schema = components[name]
        if name in out or "properties" not in schema:
            continue
        out[name] = set(schema["properties"])
        todo.extend(_nested_refs(schema["properties"]))
    return out


def contract_shapes() -> dict[str, set[str]]:
    """``{"POST /v1/transition": {...}, "stream start": {...}, "PoseMotion": {...}, ...}``: every request shape of
    the contract and its field names."""
    from service.app import create_app
    from service.schemas import CLIENT_MESSAGE

    api = create_app().openapi()
    components = api["components"]["schemas"]
    bodies = {f"{method.upper()} {path}": op["requestBody"]["content"]["application/json"]["schema"]
              for path, ops in api["paths"].items() for method, op in ops.items()
              if "application/json" in op.get("requestBody", {}).get("content", {})}
    shapes = _shapes(bodies, components)
    stream = CLIENT_MESSAGE.json_schema(ref_template="#/$defs/{model}")
    messages = {}
    for choice in stream["oneOf"]:
        name, schema = _resolve(choice, stream["$defs"])
        messages[f"stream {schema['properties']['type']['const']}"] = {"$ref": f"#/$defs/{name}"}
    for name, fields in _shapes(messages, stream["$defs"]).items():
        if name in shapes and shapes[name] != fields:
            raise AssertionError(f"{name}: the HTTP and stream schemas disagree ({shapes[name]} vs {fields})")
        shapes[name] = fields
    return shapes


# ---------------------------------------------------------------------- the clients' source

def _python_function(tree: ast.Module, qualname: str) -> ast.AST:
    node: ast.AST = tree
    for part in qualname.split("."):
        found = [n for n in ast.iter_child_nodes(node)
                 if isinstance(n, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef) and n.name == part]
        if len(found) != 1:
            raise LookupError(f"{qualname}: {len(found)} definitions of {part!r}")
        node = found[0]
    return node


def python_keys(path: Path, qualname: str) -> set[str]:
    """The string constants of one function (``Class.method`` or ``function``) of a Python module."""
    node = _python_function(ast.parse(path.read_text(encoding="utf-8")), qualname)
    return {n.value for n in ast.walk(node) if isinstance(n, ast.Constant) and isinstance(n.value, str)}


_SKIP = re.compile(r'"(?:\\.|[^"\\])*"|\'(?:\\.|[^\'\\])*\'|//[^\n]*|/\*.*?\*/', re.S)
_JSON_KEY = re.compile(r'\\"([A-Za-z_][A-Za-z0-9_]*)\\":')


def braced_body(text: str, name: str) -> str:
    """The body of the one C# or C++ function definition ``name`` in ``text`` (``Type Name(...) {...}``), its
    braces matched outside string and character literals and comments."""
    heads = list(re.finditer(rf"[\w>\]]\s+(?:\w+::)?{re.escape(name)}\s*\([^;{{}}]*\)\s*(?:const\s*)?\{{", text))
    if len(heads) != 1:
        raise LookupError(f"{name}: {len(heads)} definitions")
    start = heads[0].end() - 1
    depth, i = 0, start
    while i < len(text):
        skipped = _SKIP.match(text, i)
        if skipped:
            i = skipped.end()
            continue
        if text[i] == "{":
            depth += 1
        elif text[i] == "}":
            depth -= 1
            if depth == 0:
                return text[start:i + 1]
        i += 1
    raise LookupError(f"{name}: unbalanced braces")


def braced_keys(path: Path, name: str) -> set[str]:
    """The JSON keys (``\\"key\\":``) that the C# or C++ function ``name`` writes."""
    return set(_JSON_KEY.findall(braced_body(path.read_text(encoding="utf-8"), name)))
