"""What a ROS 2 node on rmw_zenoh expects to see on the Zenoh network (EXPERIMENTAL: written from
rmw_zenoh's published design, not yet tried against a real ROS 2 install; the tests check our side of it).

- Data key: `<domain>/<topic without leading '/'>/<package>::msg::dds_::<Type>_/<type hash>`, payload =
  the message in CDR with its 4-byte encapsulation header (what rosbags' `serialize_cdr` writes).
  Humble has no type hashes: rmw_zenoh there writes `TypeHashNotSupported`; Iron and later the RIHS01 hash.
- Attachment of every sample: sequence number (int64), source timestamp (int64 ns), 16-byte publisher GID,
  in Zenoh's own serialization (zenoh.ext.z_serialize).
- Discovery: one liveliness token per entity, `@ros2_lv/<domain>/<session zid>/<node id>/<entity id>/<kind>/
  <enclave>/<namespace>/<node name>[/<topic>/<type>/<hash>/<qos>]`, '/' in names replaced by '%', an empty
  name written '%'; kind NN (node), MP (publisher), MS (subscription). QoS:
  `<reliability>:<durability>:<history>,<depth>:<deadline s>,<ns>:<lifespan s>,<ns>:<liveliness>,<s>,<ns>`
  with rmw's enum numbers (reliable 1, volatile 2, keep_last 1) and empty fields for defaults.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from zenoh import ZBytes
from zenoh.ext import Int64, z_deserialize, z_serialize

from courtloc.ros import types

ADMIN_SPACE = "@ros2_lv"
NO_HASH = "TypeHashNotSupported"
Distro = Literal["humble", "jazzy"]


def mangle(name: str) -> str:
    stripped = name.strip("/")
    return stripped.replace("/", "%") if stripped else "%"


def type_hash(msgtype: str, distro: Distro) -> str:
    return NO_HASH if distro == "humble" else types.typestore().hash_rihs01(msgtype)


def data_key(domain_id: int, topic: str, msgtype: str, distro: Distro) -> str:
    return f"{domain_id}/{topic.strip('/')}/{types.dds_type_name(msgtype)}/{type_hash(msgtype, distro)}"


def data_key_any_hash(domain_id: int, topic: str, msgtype: str) -> str:
    """Subscriptions match every distro's hash segment."""
    return f"{domain_id}/{topic.strip('/')}/{types.dds_type_name(msgtype)}/*"


def qos_string(reliable: bool = True, depth: int = 10, transient_local: bool = False) -> str:
    return f"{1 if reliable else 2}:{1 if transient_local else 2}:1,{depth}:,:,:,,"


@dataclass(frozen=True)
class Node:
    domain_id: int
    zid: str  # our Zenoh session id, as text
    node_id: int
    name: str
    namespace: str = "/"
    enclave: str = "/"

    def _prefix(self, entity_id: int, kind: str) -> str:
        return (f"{ADMIN_SPACE}/{self.domain_id}/{self.zid}/{self.node_id}/{entity_id}/{kind}/"
                f"{mangle(self.enclave)}/{mangle(self.namespace)}/{self.name}")

    def token(self) -> str:
        return self._prefix(self.node_id, "NN")

    def endpoint_token(self, entity_id: int, kind: Literal["MP", "MS"], topic: str, msgtype: str,
                       distro: Distro, qos: str) -> str:
        return (f"{self._prefix(entity_id, kind)}/{mangle(topic)}/{types.dds_type_name(msgtype)}/"
                f"{type_hash(msgtype, distro)}/{qos}")


def attachment(sequence: int, source_timestamp_ns: int, gid: bytes) -> bytes:
    if len(gid) != 16:
        raise ValueError("a publisher GID has 16 bytes")
    return bytes(z_serialize((Int64(sequence), Int64(source_timestamp_ns), bytes(gid))))


def parse_attachment(data: bytes) -> tuple[int, int, bytes]:
    sequence, stamp, gid = z_deserialize(tuple[Int64, Int64, bytes], ZBytes(data))
    return int(sequence), int(stamp), bytes(gid)
