#!/usr/bin/env python3
"""Validates recorded protocol messages against docs/schemas/*.json (jsonschema, draft 2020-12).

    validate_schemas.py SCHEMA_DIR MESSAGES.jsonl

Each line of MESSAGES.jsonl is {"dir": "server"|"client", "msg": {...}}. The schema is chosen
by the message's "type". Fails when a message is invalid or when a schema was never exercised.
"""

import json
import pathlib
import sys

import jsonschema


def main():
    schema_dir = pathlib.Path(sys.argv[1])
    schemas = {}
    for path in sorted(schema_dir.glob("*.json")):
        schema = json.loads(path.read_text())
        jsonschema.Draft202012Validator.check_schema(schema)
        schemas[path.stem] = jsonschema.Draft202012Validator(schema)
    seen = {name: 0 for name in schemas}
    failures = []
    lines = pathlib.Path(sys.argv[2]).read_text().splitlines()
    for n, line in enumerate(lines, 1):
        record = json.loads(line)
        msg = record["msg"]
        kind = msg.get("type")
        if kind not in schemas:
            failures.append(f"line {n}: no schema for type {kind!r}")
            continue
        seen[kind] += 1
        for error in schemas[kind].iter_errors(msg):
            failures.append(f"line {n} ({record['dir']} {kind}): {error.json_path}: {error.message}")
    unused = [name for name, count in seen.items() if count == 0]
    if unused:
        failures.append(f"schemas never exercised: {', '.join(unused)}")
    for f in failures:
        print(f, file=sys.stderr)
    print(f"validated {len(lines)} messages: " + ", ".join(f"{k} {v}" for k, v in sorted(seen.items())))
    sys.exit(1 if failures else 0)


if __name__ == "__main__":
    main()
