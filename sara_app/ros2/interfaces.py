"""The ROS 2 message types the bridge speaks, written once as field lists (the ROS 2 Jazzy
interface definitions of ``common_interfaces`` / ``rcl_interfaces``), from which come:

- the ``ros2msg`` schema text (a type's definition, then each type it uses after a separator
  line) that the CDR library (``mcap_ros2``, Foxglove's maintained ROS 2 CDR codec) builds its
  encoder and decoder from: :func:`codec`;
- the type hash ``RIHS01_<sha256>`` of REP 2016 that rmw_zenoh puts in every key expression:
  :func:`type_hash` (the SHA-256 of the type description as JSON with the referenced types
  sorted by name; field type ids of ``type_description_interfaces/msg/FieldType``). Checked in
  the tests against the published hash of ``std_msgs/msg/String``.
"""

from __future__ import annotations

import hashlib
import json
from functools import cache
from typing import Any

FIELDS: dict[str, tuple[tuple[str, str], ...]] = {
    "builtin_interfaces/msg/Time": (("int32", "sec"), ("uint32", "nanosec")),
    "builtin_interfaces/msg/Duration": (("int32", "sec"), ("uint32", "nanosec")),
    "std_msgs/msg/String": (("string", "data"),),
    "std_msgs/msg/Header": (("builtin_interfaces/msg/Time", "stamp"), ("string", "frame_id")),
    "std_msgs/msg/ColorRGBA": (("float32", "r"), ("float32", "g"), ("float32", "b"),
                               ("float32", "a")),
    "geometry_msgs/msg/Point": (("float64", "x"), ("float64", "y"), ("float64", "z")),
    "geometry_msgs/msg/Vector3": (("float64", "x"), ("float64", "y"), ("float64", "z")),
    "geometry_msgs/msg/Quaternion": (("float64", "x"), ("float64", "y"), ("float64", "z"),
                                     ("float64", "w")),
    "geometry_msgs/msg/Pose": (("geometry_msgs/msg/Point", "position"),
                               ("geometry_msgs/msg/Quaternion", "orientation")),
    "sensor_msgs/msg/JointState": (
        ("std_msgs/msg/Header", "header"), ("string[]", "name"), ("float64[]", "position"),
        ("float64[]", "velocity"), ("float64[]", "effort"),
    ),
    "sensor_msgs/msg/CompressedImage": (("std_msgs/msg/Header", "header"), ("string", "format"),
                                        ("uint8[]", "data")),
    "visualization_msgs/msg/UVCoordinate": (("float32", "u"), ("float32", "v")),
    "visualization_msgs/msg/MeshFile": (("string", "filename"), ("uint8[]", "data")),
    "visualization_msgs/msg/Marker": (
        ("std_msgs/msg/Header", "header"), ("string", "ns"), ("int32", "id"), ("int32", "type"),
        ("int32", "action"), ("geometry_msgs/msg/Pose", "pose"),
        ("geometry_msgs/msg/Vector3", "scale"), ("std_msgs/msg/ColorRGBA", "color"),
        ("builtin_interfaces/msg/Duration", "lifetime"), ("bool", "frame_locked"),
        ("geometry_msgs/msg/Point[]", "points"), ("std_msgs/msg/ColorRGBA[]", "colors"),
        ("string", "texture_resource"), ("sensor_msgs/msg/CompressedImage", "texture"),
        ("visualization_msgs/msg/UVCoordinate[]", "uv_coordinates"), ("string", "text"),
        ("string", "mesh_resource"), ("visualization_msgs/msg/MeshFile", "mesh_file"),
        ("bool", "mesh_use_embedded_materials"),
    ),
    "visualization_msgs/msg/MarkerArray": (("visualization_msgs/msg/Marker[]", "markers"),),
}  # fmt: skip
"""Type name -> ``(field type, field name)`` in declaration order (constants are not part of a
type's layout or hash)."""

MARKER_CYLINDER, MARKER_SPHERE, MARKER_TRIANGLE_LIST = 3, 2, 11
MARKER_ADD, MARKER_DELETEALL = 0, 3
"""``visualization_msgs/msg/Marker`` constants."""

_TYPE_IDS = {"int8": 2, "uint8": 3, "int16": 4, "uint16": 5, "int32": 6, "uint32": 7,
             "int64": 8, "uint64": 9, "float32": 10, "float64": 11, "char": 13, "bool": 15,
             "byte": 16, "string": 17, "wstring": 18}  # fmt: skip
_NESTED = 1
_UNBOUNDED_SEQUENCE = 144
"""``type_description_interfaces/msg/FieldType``: base ids, and the offset of ``T[]``."""


def _base(field_type: str) -> tuple[str, bool]:
    return (field_type[:-2], True) if field_type.endswith("[]") else (field_type, False)


def _referenced(type_name: str) -> list[str]:
    """Every type ``type_name`` uses, transitively, sorted by name."""
    seen: set[str] = set()
    todo = [type_name]
    while todo:
        for ftype, _ in FIELDS[todo.pop()]:
            base, _ = _base(ftype)
            if base in FIELDS and base not in seen:
                seen.add(base)
                todo.append(base)
    return sorted(seen)


def _description(type_name: str) -> dict[str, Any]:
    fields = []
    for ftype, name in FIELDS[type_name]:
        base, seq = _base(ftype)
        nested = base in FIELDS
        type_id = (_NESTED if nested else _TYPE_IDS[base]) + (_UNBOUNDED_SEQUENCE if seq else 0)
        ftype_doc = {"type_id": type_id, "capacity": 0, "string_capacity": 0,
                     "nested_type_name": base if nested else ""}  # fmt: skip
        fields.append({"name": name, "type": ftype_doc})
    return {"type_name": type_name, "fields": fields}


@cache
def type_hash(type_name: str) -> str:
    """REP 2016's ``RIHS01_`` hash of ``type_name``."""
    doc = {
        "type_description": _description(type_name),
        "referenced_type_descriptions": [_description(t) for t in _referenced(type_name)],
    }
    return "RIHS01_" + hashlib.sha256(json.dumps(doc).encode()).hexdigest()


def schema_text(type_name: str) -> str:
    """The ``ros2msg`` schema of ``type_name`` with its dependencies."""
    sep = "=" * 80

    def short(t: str) -> str:  # the schema format names types pkg/Type
        return t.replace("/msg/", "/")

    def body(t: str) -> str:
        return "\n".join(f"{short(ftype)} {name}" for ftype, name in FIELDS[t]) + "\n"

    parts = [body(type_name)]
    parts += [f"{sep}\nMSG: {short(t)}\n{body(t)}" for t in _referenced(type_name)]
    return "".join(parts)


@cache
def codec(type_name: str) -> tuple[Any, Any]:
    """``(encode(dict) -> bytes, decode(bytes) -> object)`` of ``type_name`` by the CDR library
    (little-endian CDR with its 4-byte encapsulation header, as rmw serialises)."""
    from mcap_ros2._dynamic import generate_dynamic, serialize_dynamic

    text = schema_text(type_name)
    return serialize_dynamic(type_name, text)[type_name], generate_dynamic(type_name, text)[
        type_name
    ]


def dds_type_name(type_name: str) -> str:
    """``sensor_msgs/msg/JointState`` -> ``sensor_msgs::msg::dds_::JointState_`` (rmw_zenoh's
    key segment)."""
    pkg, kind, name = type_name.split("/")
    return f"{pkg}::{kind}::dds_::{name}_"
