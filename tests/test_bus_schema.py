"""The contract's JSON Schema: the file in the repository is what the message models generate
(regenerated with ``python -m sara_app.bus.schema``), every kind's example validates against it,
and messages the decoder refuses for their shape are refused by the schema too."""

from __future__ import annotations

import json
import re

import pytest
from jsonschema import Draft202012Validator

from sara_app.bus.examples import example_messages
from sara_app.bus.keys import KINDS
from sara_app.bus.messages import encode
from sara_app.bus.schema import SCHEMA_PATH, message_schema, schema_text

SCHEMA = message_schema()


def test_the_checked_in_schema_is_the_generated_one() -> None:
    assert SCHEMA_PATH.read_text() == schema_text(), (
        "messages.schema.json is stale: python -m sara_app.bus.schema > " + str(SCHEMA_PATH)
    )
    Draft202012Validator.check_schema(SCHEMA)
    assert sorted(SCHEMA["x-sara-keys"]) == sorted(KINDS)


def _validator(kind: str) -> Draft202012Validator:
    ref = SCHEMA["x-sara-keys"][kind]["$ref"]
    return Draft202012Validator({"$ref": ref, "$defs": SCHEMA["$defs"]})


@pytest.mark.parametrize("kind", sorted(KINDS))
def test_every_example_validates_and_its_key_matches(kind: str) -> None:
    key, msg = example_messages()[kind]
    data = json.loads(encode(msg))
    _validator(kind).validate(data)
    Draft202012Validator(SCHEMA).validate(data)  # the oneOf document accepts it too
    pattern = re.escape(SCHEMA["x-sara-keys"][kind]["key"])
    pattern = pattern.replace(re.escape("<cell>"), "[^/]+").replace(re.escape("<id>"), "[^/]+")
    assert re.fullmatch(pattern, key), (pattern, key)


@pytest.mark.parametrize(
    ("kind", "change"),
    [
        ("skeleton", {"schema_version": 99}),
        ("robot_state", {"q": "not a list"}),
        ("robot_command", {"mode": "stop"}),
        ("tracker_frame", {"people": [1, 2]}),
        ("controller_status", {"commands_lost": -1}),
        ("verdict", {"seq": -5}),
    ],
)
def test_the_schema_refuses_what_the_decoder_refuses(kind: str, change: dict) -> None:
    _, msg = example_messages()[kind]
    data = json.loads(encode(msg)) | change
    assert not _validator(kind).is_valid(data)
