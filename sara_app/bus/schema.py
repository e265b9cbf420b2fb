"""The JSON Schema of every bus message, generated from the pydantic models of
:mod:`sara_app.bus.messages` (the contract's machine-readable half: ``CONTRACT.md`` says what
the fields mean, ``messages.schema.json`` what they may hold).

One document: ``$defs`` holds each message kind's schema; ``oneOf`` accepts any of them;
``x-sara-keys`` maps each kind to its key and its schema. A test checks that the file in the
repository equals what the models generate; after changing a message model, regenerate it::

    python -m sara_app.bus.schema > sara_app/bus/messages.schema.json
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any, Literal

from pydantic.json_schema import models_json_schema

from sara_app.bus import keys
from sara_app.bus.messages import MODELS_BY_KIND

SCHEMA_PATH = Path(__file__).with_name("messages.schema.json")


def message_schema() -> dict[str, Any]:
    """The schema document (see the module docstring)."""
    mode: Literal["validation"] = "validation"
    models = [(MODELS_BY_KIND[k], mode) for k in keys.KINDS]
    refs, doc = models_json_schema(models, ref_template="#/$defs/{model}")
    kinds = {
        kind: {
            "key": keys.key_pattern(kind),
            "$ref": refs[(MODELS_BY_KIND[kind], "validation")]["$ref"],
        }
        for kind in keys.KINDS
    }
    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": f"SaRA cell bus messages (key scheme {keys.KEY_SCHEME})",
        "oneOf": [{"$ref": v["$ref"]} for v in kinds.values()],
        "x-sara-keys": kinds,
        "$defs": doc["$defs"],
    }


def schema_text() -> str:
    return json.dumps(message_schema(), indent=1, sort_keys=True) + "\n"


if __name__ == "__main__":
    sys.stdout.write(schema_text())
