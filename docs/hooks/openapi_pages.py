"""MkDocs hook: the HTTP API pages, made at build time from the committed OpenAPI spec (openapi/openapi.json,
written by `make openapi`), with no network and no Swagger UI: ``api/http.md`` lists every route with its query
parameters, request bodies and answers, ``api/models.md`` every model with its fields, as Markdown tables."""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

from mkdocs.structure.files import File, Files

ROOT = Path(__file__).resolve().parents[2]
SPEC = ROOT / "openapi" / "openapi.json"
REF = "#/components/schemas/"


def cell(text: object) -> str:
    """Text made safe for one Markdown table cell: one line, pipes escaped, and angle brackets outside code spans
    shown as text (a description's `<name>.onnx` is not an HTML tag, its `{"preset": string}` no attribute list)."""
    parts = re.sub(r"\s*\n\s*", " ", str(text)).replace("|", "\\|").strip().split("`")
    return "`".join(part if i % 2 else part.replace("<", "&lt;").replace(">", "&gt;").replace("{", "&#123;")
                    for i, part in enumerate(parts))


def anchor(name: str) -> str:
    """The anchor MkDocs' toc gives a heading that is a bare model name."""
    return name.lower()


def type_of(schema: dict[str, Any], models: str = "") -> str:
    """A short reading of a JSON schema: a model link, a type with its constraints, a union."""
    if "$ref" in schema:
        name = schema["$ref"].removeprefix(REF)
        return f"[{name}]({models}#{anchor(name)})"
    for key in ("anyOf", "oneOf", "allOf"):
        if key in schema:
            return " or ".join(type_of(s, models) for s in schema[key])
    if "enum" in schema:
        return " or ".join(f"`{json.dumps(v)}`" for v in schema["enum"])
    if "const" in schema:
        return f"`{json.dumps(schema['const'])}`"
    kind = schema.get("type", "any")
    if kind == "array":
        items = schema.get("items", {})
        text = f"array of {type_of(items, models)}" if items else "array"
        lo, hi = schema.get("minItems"), schema.get("maxItems")
        if lo is not None and lo == hi:
            text += f" ({lo} items)"
        elif lo is not None or hi is not None:
            text += f" ({lo if lo is not None else 0} to {hi if hi is not None else 'any'} items)"
        return text
    if kind == "object" and isinstance(schema.get("additionalProperties"), dict):
        return f"object of {type_of(schema['additionalProperties'], models)}"
    text = str(kind)
    if "format" in schema:
        text += f" ({schema['format']})"
    bounds = [f"{word} {schema[key]}" for key, word in (("minimum", "≥"), ("exclusiveMinimum", ">"),
                                                         ("maximum", "≤"), ("exclusiveMaximum", "<"),
                                                         ("minLength", "length ≥"), ("maxLength", "length ≤"))
              if key in schema]
    if "pattern" in schema:
        bounds.append(f"matches `{schema['pattern']}`")
    return text + (f" ({', '.join(bounds)})" if bounds else "")


def default_of(schema: dict[str, Any]) -> str:
    return f"`{json.dumps(schema['default'])}`" if "default" in schema else ""


def properties_table(schema: dict[str, Any], models: str) -> list[str]:
    """The fields of an object schema as a table."""
    required = set(schema.get("required", []))
    rows = ["| field | type | required | default | description |", "|---|---|---|---|---|"]
    for name, prop in schema.get("properties", {}).items():
        rows.append(f"| `{name}` | {cell(type_of(prop, models))} | {'yes' if name in required else ''} | "
                    f"{cell(default_of(prop))} | {cell(prop.get('description', ''))} |")
    return rows


def http_page(spec: dict[str, Any]) -> str:
    """Every route: summary, description, authentication, query parameters, request bodies, answers."""
    out = ["# HTTP routes", "",
           f"*Made from `openapi/openapi.json` (the service's OpenAPI {spec['openapi']} spec, version "
           f"{spec['info']['version']}) when the site was built. A running server serves the same spec at "
           "`/openapi.json` and its own pages at `/docs` and `/redoc`.*", "",
           spec["info"].get("description", "").strip(), "",
           "| method | path | summary |", "|---|---|---|"]
    operations = [(path, method, op) for path, ops in spec["paths"].items() for method, op in ops.items()]
    for path, method, op in operations:
        out.append(f"| {method.upper()} | [`{path}`](#{op['operationId']}) | {cell(op.get('summary', ''))} |")
    for path, method, op in operations:
        out += ["", f"## {method.upper()} {path} {{#{op['operationId']}}}", ""]
        if op.get("summary"):
            out += [f"**{op['summary']}.**", ""]
        if op.get("description"):
            out += [op["description"].strip(), ""]
        out += ["Needs the bearer token when the server has one (`GRASPD_TOKEN`)." if op.get("security")
                else "Open to anyone.", ""]
        params = op.get("parameters", [])
        if params:
            out += ["| parameter | in | type | required | description |", "|---|---|---|---|---|"]
            for p in params:
                out.append(f"| `{p['name']}` | {p['in']} | {cell(type_of(p.get('schema', {}), 'models.md'))} | "
                           f"{'yes' if p.get('required') else ''} | {cell(p.get('description', ''))} |")
            out.append("")
        body = op.get("requestBody")
        if body:
            out += [f"Request body{' (required)' if body.get('required') else ''}: {cell(body.get('description', ''))}",
                    "", "| content type | body |", "|---|---|"]
            forms = []
            for ctype, content in body["content"].items():
                schema = content.get("schema", {})
                if "properties" in schema:
                    forms.append((ctype, schema))
                    out.append(f"| `{ctype}` | the form fields below |")
                else:
                    out.append(f"| `{ctype}` | {cell(type_of(schema, 'models.md'))} |")
            out.append("")
            for ctype, schema in forms:
                out += [f"Fields of `{ctype}`:", "", *properties_table(schema, "models.md"), ""]
        out += ["| status | meaning | body |", "|---|---|---|"]
        for status, answer in op.get("responses", {}).items():
            bodies = ", ".join(f"{cell(type_of(c.get('schema', {}), 'models.md'))} (`{t}`)"
                               for t, c in answer.get("content", {}).items())
            out.append(f"| {status} | {cell(answer.get('description', ''))} | {bodies} |")
    return "\n".join(out) + "\n"


def models_page(spec: dict[str, Any]) -> str:
    """Every model of the spec, its description and its fields."""
    schemas = spec["components"]["schemas"]
    out = ["# HTTP models", "",
           "*Made from `openapi/openapi.json` when the site was built: the JSON bodies of the "
           "[HTTP routes](http.md), which travel unchanged over Zenoh.*", "",
           " · ".join(f"[{name}](#{anchor(name)})" for name in schemas)]
    for name, schema in schemas.items():
        out += ["", f"## {name}", ""]
        if schema.get("description"):
            out += [schema["description"].strip(), ""]
        if "properties" in schema:
            out += properties_table(schema, "")
            if schema.get("additionalProperties") is False:
                out += ["", "Other fields are refused (422)."]
        else:
            out.append(f"Type: {type_of(schema)}")
    return "\n".join(out) + "\n"


def on_files(files: Files, config: Any, **_: Any) -> Files:
    spec = json.loads(SPEC.read_text(encoding="utf-8"))
    files.append(File.generated(config, "api/http.md", content=http_page(spec)))
    files.append(File.generated(config, "api/models.md", content=models_page(spec)))
    return files
