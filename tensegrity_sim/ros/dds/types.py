"""DDS types generated from ROS 2 message definitions, named the way ROS 2 names them on the wire.

A ROS 2 message ``pkg/msg/Type`` travels over DDS as a keyless, final (``@final``) struct named
``pkg::msg::dds_::Type_``, encoded in XCDR1 (plain CDR), on a topic whose name is the ROS name with
``rt`` prefixed (``/tensegrity_sim/node_poses`` -> ``rt/tensegrity_sim/node_poses``). Endpoints carry
the type's RIHS01 hash in their USER_DATA as ``typehash=RIHS01_<hex>;``.

Nothing here copies a message layout by hand: the structs are generated from the field definitions of
:data:`~tensegrity_sim.ros.messages.TYPESTORE` (rosbags' ROS 2 Jazzy store, the one the node's messages
and the MCAP log use), and the hash is its ``hash_rihs01`` (the same computation as ``rosidl``'s
type-description hash).
"""
from __future__ import annotations

import re
from dataclasses import dataclass
from functools import cache

from cyclonedds.idl import IdlStruct, make_idl_struct
from cyclonedds.idl import types as t
from cyclonedds.idl.annotations import final
from rosbags.interfaces import Nodetype

from ..messages import TYPESTORE

__all__ = ["DdsType", "dds_topic_name", "dds_type"]

# ROS 2 primitive -> IDL primitive. ``char`` is uint8, as in rosidl. ``byte`` is octet in rosidl's IDL but
# uint8 in the XTypes type information that rmw_cyclonedds builds (its dynamic types, in releases after
# Jazzy's, which sends none and matches by type name only): a peer that compares type information
# compares it with that, and the two encode alike (one byte).
_PRIMITIVES = {
    "bool": bool, "byte": t.uint8, "char": t.uint8,
    "int8": t.int8, "uint8": t.uint8, "int16": t.int16, "uint16": t.uint16,
    "int32": t.int32, "uint32": t.uint32, "int64": t.int64, "uint64": t.uint64,
    "float32": t.float32, "float64": t.float64, "string": str,
}
_ROS_NAME = re.compile(r"^(/[A-Za-z_][A-Za-z0-9_]*)+$")  # fully qualified: /ns/name


@dataclass(frozen=True)
class DdsType:
    """One ROS 2 message type as DDS sees it.

    msgtype: the ROS name, ``pkg/msg/Type``. dds_name: ``pkg::msg::dds_::Type_``.
    idl: the generated cyclonedds struct (keyless, final, nested types generated alike).
    type_hash: ``RIHS01_<sha256 hex>``, what Jazzy puts in USER_DATA.
    """

    msgtype: str
    dds_name: str
    idl: type[IdlStruct]
    type_hash: str

    @property
    def user_data(self) -> bytes:
        """The USER_DATA of a ROS 2 Jazzy reader or writer of this type."""
        return f"typehash={self.type_hash};".encode()


def dds_type_name(msgtype: str) -> str:
    """``pkg/msg/Type`` -> ``pkg::msg::dds_::Type_`` (the rosidl_typesupport naming)."""
    pkg, kind, name = msgtype.split("/")
    return f"{pkg}::{kind}::dds_::{name}_"


def dds_topic_name(ros_topic: str) -> str:
    """A fully qualified ROS topic name (``/ns/name``) -> its DDS topic (``rt/ns/name``).

    Raises ValueError for a name that is not absolute or not a valid ROS name.
    """
    if not isinstance(ros_topic, str) or not _ROS_NAME.match(ros_topic):
        raise ValueError(f"topic must be a fully qualified ROS name like /ns/name, got {ros_topic!r}")
    return "rt" + ros_topic


@cache
def dds_type(msgtype: str) -> DdsType:
    """The DDS type of ``msgtype`` (``pkg/msg/Type``), generated once. ValueError for an unknown type."""
    if msgtype not in TYPESTORE.fielddefs:
        raise ValueError(f"message type {msgtype!r} is not defined in the typestore")
    return DdsType(msgtype, dds_type_name(msgtype), _idl_struct(msgtype), TYPESTORE.hash_rihs01(msgtype))


def _idl_struct(msgtype: str) -> type[IdlStruct]:
    """Generate the IDL struct of ``msgtype`` and, through :func:`dds_type`, of the types it nests."""
    _, fields = TYPESTORE.fielddefs[msgtype]
    members = {name: _idl_member(desc) for name, desc in fields}
    return final(make_idl_struct(msgtype.rsplit("/", 1)[1] + "_", dds_type_name(msgtype), members))


def _idl_member(desc):
    """The cyclonedds annotation of one rosbags field description ``(Nodetype, detail)``."""
    node, detail = desc
    if node == Nodetype.BASE:
        name, bound = detail
        return t.bounded_str[bound] if name == "string" and bound else _PRIMITIVES[name]
    if node == Nodetype.NAME:
        return dds_type(detail).idl
    element, count = detail
    if node == Nodetype.ARRAY:
        return t.array[_idl_member(element), count]
    # A sequence: bounded when count > 0.
    return t.sequence[_idl_member(element), count] if count else t.sequence[_idl_member(element)]
