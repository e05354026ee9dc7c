"""OpenAPI 3.0's dialect of JSON Schema, which OGC API - Processes 1.0 speaks: the API's
definition for the ``oas30`` conformance class (and clients such as OWSLib that look for
a 3.0 service-desc), and the schemas of the process descriptions.

FastAPI writes OpenAPI 3.1, whose schemas are JSON Schema 2020-12 (as
:func:`treesim.params.json_schema` writes them too). :func:`schema30` rewrites one
Schema Object: ``anyOf``/``oneOf`` with a null alternative and type lists become
``nullable``; ``const`` a one-value ``enum``; numeric ``exclusiveMinimum``/
``exclusiveMaximum`` the bound with a boolean; ``examples`` the first ``example``; the
unit (``x-unit``) goes into the description; a ``$ref`` with siblings becomes an
``allOf`` of the reference; ``prefixItems`` its ``items``; keywords OpenAPI 3.0 has not
(``$schema``, ...) are left out. :func:`to_openapi30` does so for every Schema Object of
a whole document and changes nothing else; ``tests/service/test_ogc.py`` checks the
result with openapi-spec-validator.
"""

from __future__ import annotations

import copy
from typing import Any

__all__ = ["OGC_KEYWORDS", "OPENAPI30_JSON", "schema30", "to_openapi30"]

#: The media type of the 3.0 document (its service-desc link's type).
OPENAPI30_JSON = "application/vnd.oai.openapi+json;version=3.0"

#: Schema Object keywords of OpenAPI 3.0.3.
_KEYWORDS = frozenset(
    "title multipleOf maximum exclusiveMaximum minimum exclusiveMinimum maxLength minLength "
    "pattern maxItems minItems uniqueItems maxProperties minProperties required enum type not "
    "allOf oneOf anyOf items properties additionalProperties description format default "
    "nullable discriminator readOnly writeOnly xml externalDocs example deprecated".split()
)
#: What OGC API - Processes 1.0's ``schema.yaml`` adds to them (a file input's media type).
OGC_KEYWORDS = frozenset({"contentMediaType", "contentEncoding", "contentSchema"})
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


def schema30(schema: Any, keep: frozenset[str] = frozenset()) -> Any:
    """One Schema Object (and those inside it) in OpenAPI 3.0's dialect; ``keep``: further
    keywords to keep (:data:`OGC_KEYWORDS` in a process description).

    Examples
    --------
    >>> s = schema30(
    ...     {"anyOf": [{"type": "number", "exclusiveMinimum": 0}, {"type": "null"}],
    ...      "x-unit": "m", "description": "range", "default": None})
    >>> s["type"], s["minimum"], s["exclusiveMinimum"], s["nullable"], s["description"]
    ('number', 0, True, True, 'range [m]')
    """
    if not isinstance(schema, dict):
        return schema
    allowed = _KEYWORDS | keep
    s = _nullable(dict(schema))
    unit = s.pop("x-unit", None)
    if unit:
        s["description"] = f"{s.get('description', '')} [{unit}]".strip()
    if "$ref" in s:
        ref = {"$ref": s.pop("$ref")}
        rest = {k: v for k, v in s.items() if k in allowed}
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
        if k not in allowed:
            continue
        if k == "properties":
            out[k] = {n: schema30(x, keep) for n, x in v.items()}
        elif k in ("allOf", "oneOf", "anyOf"):
            out[k] = [schema30(x, keep) for x in v]
        elif k in ("items", "not", "additionalProperties") and isinstance(v, dict):
            out[k] = schema30(v, keep)
        else:
            out[k] = v
    return out


def _content(content: dict[str, Any]) -> None:
    for media in content.values():
        if isinstance(media, dict) and "schema" in media:
            media["schema"] = schema30(media["schema"])


def _operation(op: dict[str, Any]) -> None:
    for p in op.get("parameters", []):
        if "schema" in p:
            p["schema"] = schema30(p["schema"])
    body = op.get("requestBody")
    if isinstance(body, dict):
        _content(body.get("content", {}))
    for resp in op.get("responses", {}).values():
        if isinstance(resp, dict):
            _content(resp.get("content", {}))
            for h in resp.get("headers", {}).values():
                if isinstance(h, dict) and "schema" in h:
                    h["schema"] = schema30(h["schema"])


def to_openapi30(doc: dict[str, Any]) -> dict[str, Any]:
    """FastAPI's OpenAPI 3.1 document ``doc`` as OpenAPI 3.0.3 (a new dict).

    Examples
    --------
    >>> d = to_openapi30({"openapi": "3.1.0", "info": {"title": "t", "version": "1"},
    ...     "paths": {}, "components": {"schemas": {"A": {"type": "object", "properties":
    ...     {"x": {"anyOf": [{"type": "number", "exclusiveMinimum": 0}, {"type": "null"}]}}}}}})
    >>> x = d["components"]["schemas"]["A"]["properties"]["x"]
    >>> d["openapi"], x == {"type": "number", "minimum": 0, "exclusiveMinimum": True,
    ...                     "nullable": True}
    ('3.0.3', True)
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
        comps["schemas"][name] = schema30(s)
    return out
