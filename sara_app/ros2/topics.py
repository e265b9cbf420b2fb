"""rmw_zenoh's wire conventions (``ros2/rmw_zenoh``, docs/design.md and its attachment helpers):

- a topic's data lives on ``<domain_id>/<topic without its leading and trailing '/'>/<DDS type
  name>/<type hash>``, e.g. ``0/chatter/std_msgs::msg::dds_::String_/RIHS01_df66...``;
- each sample carries an attachment: the publisher's sequence number (int64), the source
  timestamp (int64, ns) and the publisher's 16-byte GID, in zenoh's own serialisation (done here
  by ``zenoh.ext.z_serialize``);
- graph discovery (``ros2 topic list``) uses liveliness tokens
  ``@ros2_lv/<domain_id>/<zenoh id>/<node id>/<entity id>/<kind>/<enclave>/<namespace>/<node>
  [/<topic>/<type>/<hash>/<qos>]`` with ``/`` in names written ``%`` (``%`` alone: empty).
"""

from __future__ import annotations

from typing import Any, cast

from zenoh import ZBytes
from zenoh.ext import Int64, UInt8, z_deserialize, z_serialize

from sara_app.errors import InputError
from sara_app.ros2.interfaces import dds_type_name, type_hash

ADMIN_SPACE = "@ros2_lv"
DEFAULT_QOS = "::,10:,:,:,,"
"""Reliable, volatile, keep-last 10, no deadline / lifespan / liveliness lease: rmw_zenoh's
encoding with empty fields for the defaults."""
GID_BYTES = 16


def topic_key(domain_id: int, topic: str, type_name: str) -> str:
    """The key expression of ``topic`` (e.g. ``/joint_states``) of ``type_name``."""
    name = topic.strip("/")
    if not name or "//" in name or any(c in name for c in "*$?#"):
        raise InputError(f"ROS 2 topic {topic!r}; expected a name like /joint_states")
    return f"{domain_id}/{name}/{dds_type_name(type_name)}/{type_hash(type_name)}"


def attachment(sequence_number: int, source_timestamp_ns: int, gid: bytes) -> bytes:
    """A sample's attachment as rmw_zenoh writes and reads it."""
    if len(gid) != GID_BYTES:
        raise InputError(f"GID of {len(gid)} bytes; expected {GID_BYTES}")
    z = z_serialize((Int64(sequence_number), Int64(source_timestamp_ns),
                     tuple(UInt8(b) for b in gid)))  # fmt: skip
    return z.to_bytes()


def read_attachment(data: bytes) -> tuple[int, int, bytes]:
    """``(sequence_number, source_timestamp_ns, gid)`` of an attachment."""
    layout: Any = tuple[Int64, Int64, tuple[(UInt8,) * GID_BYTES]]  # type: ignore[misc]
    seq, ts, gid = cast(tuple[Any, Any, Any], z_deserialize(layout, ZBytes(data)))
    return int(seq), int(ts), bytes(int(b) for b in gid)


def _mangle(name: str) -> str:
    return name.replace("/", "%") if name.strip("/") else "%"


def liveliness_key(
    domain_id: int,
    zid: str,
    node_id: int,
    entity_id: int,
    kind: str,
    node: str,
    namespace: str = "/",
    topic: str | None = None,
    type_name: str | None = None,
) -> str:
    """A liveliness token's key: ``kind`` ``NN`` (node), ``MP`` (publisher) or ``MS``
    (subscription; then ``topic`` and ``type_name``)."""
    base = (f"{ADMIN_SPACE}/{domain_id}/{zid}/{node_id}/{entity_id}/{kind}/%/"
            f"{_mangle(namespace)}/{node}")  # fmt: skip
    if kind == "NN":
        return base
    if topic is None or type_name is None:
        raise InputError(f"a {kind} token needs its topic and type")
    return (f"{base}/{_mangle('/' + topic.strip('/'))}/{dds_type_name(type_name)}/"
            f"{type_hash(type_name)}/{DEFAULT_QOS}")  # fmt: skip
