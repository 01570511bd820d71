#!/usr/bin/env python3
"""Validates recorded protocol messages against docs/schemas/*.json (jsonschema, draft 2020-12).

    validate_schemas.py SCHEMA_DIR MESSAGES.jsonl [--partial]
    validate_schemas.py SCHEMA_DIR --docs PAGE.md...

Each line of MESSAGES.jsonl is {"dir": "server"|"client", "msg": {...}}. The schema is chosen
by the message's "type". Fails when a message is invalid or when a schema was never exercised
(unless --partial: a run that records only some kinds of message).

With --docs, the messages are the examples in the pages' ```json blocks (every JSON object
with a "type" in them: a block is one object, or one object per line). An example shortens a
list with the string "…" as an element ("points":["P1","P2","…"]): those elements are left
out before validation; every other value is validated as written.
"""

import json
import pathlib
import sys

import jsonschema


ELLIPSIS = "\u2026"


def without_ellipses(value):
    """The example with its "…" list elements left out."""
    if isinstance(value, list):
        return [without_ellipses(v) for v in value if v != ELLIPSIS]
    if isinstance(value, dict):
        return {k: without_ellipses(v) for k, v in value.items()}
    return value


def doc_examples(pages):
    """(where, message) for every JSON example with a "type" in the pages' ```json blocks."""
    for page in pages:
        text = pathlib.Path(page).read_text()
        block, start = None, 0
        for n, line in enumerate(text.splitlines(), 1):
            if block is None and line.strip() == "```json":
                block, start = [], n + 1
            elif block is not None and line.strip() == "```":
                body = "\n".join(block)
                try:
                    objects = [(start, json.loads(body))]
                except json.JSONDecodeError:
                    objects = [(start + i, json.loads(l)) for i, l in enumerate(block) if l.strip()]
                for line_no, obj in objects:
                    if isinstance(obj, dict) and "type" in obj:
                        yield f"{page}:{line_no}", without_ellipses(obj)
                block = None
            elif block is not None:
                block.append(line)


def main():
    schema_dir = pathlib.Path(sys.argv[1])
    schemas = {}
    for path in sorted(schema_dir.glob("*.json")):
        schema = json.loads(path.read_text())
        jsonschema.Draft202012Validator.check_schema(schema)
        schemas[path.stem] = jsonschema.Draft202012Validator(schema)
    seen = {name: 0 for name in schemas}
    failures = []
    if sys.argv[2] == "--docs":
        records = [(where, {"dir": "docs", "msg": msg}) for where, msg in doc_examples(sys.argv[3:])]
        partial = True
    else:
        lines = pathlib.Path(sys.argv[2]).read_text().splitlines()
        records = [(f"line {n}", json.loads(line)) for n, line in enumerate(lines, 1)]
        partial = "--partial" in sys.argv[3:]
    for n, record in records:
        msg = record["msg"]
        kind = msg.get("type")
        if kind not in schemas:
            failures.append(f"{n}: no schema for type {kind!r}")
            continue
        seen[kind] += 1
        for error in schemas[kind].iter_errors(msg):
            failures.append(f"{n} ({record['dir']} {kind}): {error.json_path}: {error.message}")
    unused = [name for name, count in seen.items() if count == 0]
    if unused and not partial:
        failures.append(f"schemas never exercised: {', '.join(unused)}")
    if not records:
        failures.append("no message to validate")
    for f in failures:
        print(f, file=sys.stderr)
    print(f"validated {len(records)} messages: " + ", ".join(f"{k} {v}" for k, v in sorted(seen.items())))
    sys.exit(1 if failures else 0)


if __name__ == "__main__":
    main()
