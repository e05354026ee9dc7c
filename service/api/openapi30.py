"""The API's definition in OpenAPI 3.0, for the ``oas30`` conformance class of OGC API -
Processes - Part 1 (and clients such as OWSLib that look for a 3.0 service-desc).

FastAPI writes OpenAPI 3.1, whose schemas are JSON Schema 2020-12. :func:`to_openapi30`
rewrites that document's Schema Objects in OpenAPI 3.0's dialect and changes nothing
else: ``anyOf``/``oneOf`` with a null alternative and type lists become ``nullable``;
``const`` a one-value ``enum``; numeric ``exclusiveMinimum``/``exclusiveMaximum`` the
bound with a boolean; ``examples`` the first ``example``; a ``$ref`` with siblings an
``allOf`` of the reference; ``prefixItems`` its ``items``; keywords OpenAPI 3.0 has not
(``contentMediaType``, ``$schema``, ...) left out. ``tests/service/test_ogc.py`` checks the
result with openapi-spec-validator.
"""

from __future__ import annotations

import copy
from typing import Any

__all__ = ["OPENAPI30_JSON", "to_openapi30"]

#: The media type of the 3.0 document (its service-desc link's type).
OPENAPI30_JSON = "application/vnd.oai.openapi+json;version=3.0"

#: Schema Object keywords of OpenAPI 3.0.3.
_KEYWORDS = frozenset(
    "title multipleOf maximum exclusiveMaximum minimum exclusiveMinimum maxLength minLength "
    "pattern maxItems minItems uniqueItems maxProperties minProperties required enum type not "
    "allOf oneOf anyOf items properties additionalProperties description format default "
    "nullable discriminator readOnly writeOnly xml externalDocs example deprecated".split()
)
_NULL = {"type": "null"}


def _nullable(s: dict[str, Any]) -> dict[str, Any]:
    for key in ("anyOf", "oneOf"):
        alts = s.get(key)
        if isinstance(alts, list) and _NULL in alts:
            rest = [a for a in alts if a != _NULL]
            del s[key]
            if len(rest) == 1:
                s = {**s, "allOf": rest} if "$ref" in rest[0] else {**rest[0], **s}
            elif rest:
                s[key] = rest
            s["nullable"] = True
    t = s.get("type")
    if isinstance(t, list):
        kinds = [x for x in t if x != "null"]
        if len(kinds) < len(t):
            s["nullable"] = True
        del s["type"]
        if len(kinds) == 1:
            s["type"] = kinds[0]
        elif kinds:
            s["anyOf"] = [{"type": x} for x in kinds]
    if s.get("type") == "null":  # null alone: nothing but null
        del s["type"]
        s["nullable"] = True
        s["enum"] = [None]
    return s


def _schema(schema: Any) -> Any:
    """One Schema Object (and those inside it) in OpenAPI 3.0's dialect."""
    if not isinstance(schema, dict):
        return schema
    s = _nullable(dict(schema))
    if "$ref" in s:
        ref = {"$ref": s.pop("$ref")}
        rest = {k: v for k, v in s.items() if k in _KEYWORDS}
        if not rest:
            return ref
        s = {**rest, "allOf": [ref, *rest.get("allOf", [])]}
    if "const" in s:
        s["enum"] = [s.pop("const")]
    if isinstance(s.get("examples"), list) and s["examples"] and "example" not in s:
        s["example"] = s["examples"][0]
    if "prefixItems" in s and "items" not in s:
        items = s["prefixItems"]
        s["items"] = items[0] if len(items) == 1 else {"anyOf": items}
    for bound, limit in (("exclusiveMinimum", "minimum"), ("exclusiveMaximum", "maximum")):
        v = s.get(bound)
        if isinstance(v, int | float) and not isinstance(v, bool):
            s[limit], s[bound] = v, True
    out: dict[str, Any] = {}
    for k, v in s.items():
        if k not in _KEYWORDS:
            continue
        if k == "properties":
            out[k] = {n: _schema(x) for n, x in v.items()}
        elif k in ("allOf", "oneOf", "anyOf"):
            out[k] = [_schema(x) for x in v]
        elif k in ("items", "not", "additionalProperties") and isinstance(v, dict):
            out[k] = _schema(v)
        else:
            out[k] = v
    return out


def _content(content: dict[str, Any]) -> None:
    for media in content.values():
        if isinstance(media, dict) and "schema" in media:
            media["schema"] = _schema(media["schema"])


def _operation(op: dict[str, Any]) -> None:
    for p in op.get("parameters", []):
        if "schema" in p:
            p["schema"] = _schema(p["schema"])
    body = op.get("requestBody")
    if isinstance(body, dict):
        _content(body.get("content", {}))
    for resp in op.get("responses", {}).values():
        if isinstance(resp, dict):
            _content(resp.get("content", {}))
            for h in resp.get("headers", {}).values():
                if isinstance(h, dict) and "schema" in h:
                    h["schema"] = _schema(h["schema"])


def to_openapi30(doc: dict[str, Any]) -> dict[str, Any]:
    """FastAPI's OpenAPI 3.1 document ``doc`` as OpenAPI 3.0.3 (a new dict).

    Examples
    --------
    >>> d = to_openapi30({"openapi": "3.1.0", "info": {"title": "t", "version": "1"},
    ...     "paths": {}, "components": {"schemas": {"A": {"type": "object", "properties":
    ...     {"x": {"anyOf": [{"type": "number", "exclusiveMinimum": 0}, {"type": "null"}]}}}}}})
    >>> d["openapi"], d["components"]["schemas"]["A"]["properties"]["x"]
    ('3.0.3', {'type': 'number', 'minimum': 0, 'exclusiveMinimum': True, 'nullable': True})
    """
    out = copy.deepcopy(doc)
    out["openapi"] = "3.0.3"
    info = out.get("info", {})
    info.pop("summary", None)  # (3.1 only)
    info.pop("license", None) if "identifier" in info.get("license", {}) else None
    out.pop("webhooks", None)
    out.pop("jsonSchemaDialect", None)
    for item in out.get("paths", {}).values():
        for key, op in item.items():
            if key == "parameters":
                _operation({"parameters": op})
            elif isinstance(op, dict):
                _operation(op)
    comps = out.get("components", {})
    for name, s in list(comps.get("schemas", {}).items()):
        comps["schemas"][name] = _schema(s)
    return out
