"""One source of ROS 2 Jazzy message types for the node, the log, the replay and the tests.

Where rclpy is importable (a sourced ROS 2 Jazzy), the classes are rclpy's own; everywhere else they are
the Jazzy types of rosbags' type store (``get_typestore(Stores.ROS2_JAZZY)``), which have the same fields
and serialise to the same CDR bytes. So the node logic, the log and the tests use real ROS message
layouts without ROS. The schema text (``ros2msg`` with its dependent definitions) and the type hash
(RIHS01) written to logs always come from rosbags' Jazzy type store.

Build messages with :func:`new` and pass every field (rosbags' classes have no defaults). Three field
kinds are represented differently in the two worlds, and the helpers below hide that:

* ``float64[]``: :func:`float64s` (numpy array for rosbags, ``array('d')`` for rclpy);
* ``uint8[]``: :func:`uint8s`;
* ``byte``: :func:`byte` (int for rosbags, a one-byte ``bytes`` for rclpy).

Read arrays back with ``np.asarray(field, dtype=float)``, which works for both.

Bytes are always rosbags' (:func:`serialize`): rclpy's ``serialize_message`` leaves alignment padding
uncleared and may append trailing bytes, so the same message would come out as different bytes (and
rosbags would refuse some: "CDR message size mismatch"). With rclpy, a message is first copied into its
rosbags twin (:func:`rosbags_message`), so logs and raw transports carry the same bytes with and without
rclpy; rclpy decodes those bytes as any CDR.
"""
from __future__ import annotations

import array
import dataclasses
from functools import cache
from importlib import import_module

import numpy as np
from rosbags.interfaces import Nodetype
from rosbags.typesys import Stores, get_typestore

__all__ = ["BACKEND", "TYPESTORE", "new", "message_class", "float64s", "uint8s", "byte", "serialize",
           "deserialize", "rosbags_message", "field_names", "schema_text", "type_hash", "time", "header", "point",
           "vector3", "color", "key_values", "joint_state", "wrench_stamped", "parameter_event", "parameter_changes"]

TYPESTORE = get_typestore(Stores.ROS2_JAZZY)

try:
    from rclpy.serialization import deserialize_message as _rclpy_deserialize
    BACKEND = "rclpy"
except ImportError:
    BACKEND = "rosbags"


@cache
def message_class(typename: str) -> type:
    """The class of ``typename`` ("pkg/msg/Name") in the active backend."""
    if BACKEND == "rclpy":
        package, kind, name = typename.split("/")
        return getattr(import_module(f"{package}.{kind}"), name)
    return TYPESTORE.types[typename]


def new(typename: str, **fields):
    """A message of ``typename`` with ``fields`` (give them all)."""
    return message_class(typename)(**fields)


def float64s(values) -> np.ndarray | array.array:
    """A ``float64[]`` field from anything array-like, without changing a bit (a copy: the message does
    not share memory with the caller's array)."""
    a = np.array(values, dtype=np.float64).reshape(-1)
    if BACKEND == "rclpy":
        out = array.array("d")
        out.frombytes(a.tobytes())
        return out
    return a


def uint8s(values=()) -> np.ndarray | array.array:
    """A ``uint8[]`` field."""
    a = np.ascontiguousarray(values, dtype=np.uint8).reshape(-1)
    if BACKEND == "rclpy":
        return array.array("B", a.tobytes())
    return a


def byte(value: int) -> int | bytes:
    """A ``byte`` field (e.g. ``DiagnosticStatus.level``)."""
    return bytes([value]) if BACKEND == "rclpy" else int(value)


def serialize(message, typename: str) -> bytes:
    """CDR bytes (little endian, with the 4-byte encapsulation header), as DDS and rosbag2 carry them,
    written by rosbags whichever the backend: padding zero, no trailing bytes."""
    return bytes(TYPESTORE.serialize_cdr(rosbags_message(message, typename), typename))


_PLACEHOLDER = "structure_needs_at_least_one_member"  # rosbags' one field of a message that has none


def rosbags_message(message, typename: str):
    """``message`` (of ``typename``, from either backend) as an object of rosbags' type store, values
    unchanged; a rosbags message is returned as it is. AttributeError for an object that lacks a field.
    (A message with no fields has one in rosbags, 0 on the wire, which rclpy hides: it is copied as 0.)"""
    if isinstance(message, TYPESTORE.types[typename]):
        return message
    _, fields = TYPESTORE.fielddefs[typename]
    return TYPESTORE.types[typename](**{
        name: _rosbags_value(getattr(message, name, 0) if name == _PLACEHOLDER else getattr(message, name), desc)
        for name, desc in fields})


def _rosbags_value(value, desc):
    """One field's value as rosbags holds it (``desc``: the field's description in ``TYPESTORE.fielddefs``)."""
    kind, detail = desc
    if kind == Nodetype.NAME:
        return rosbags_message(value, detail)
    if kind == Nodetype.BASE:
        # rclpy holds a ``byte`` as a one-byte bytes object, rosbags as an int
        return value[0] if isinstance(value, bytes) else value
    (element_kind, element), _ = detail  # an array or a sequence
    if element_kind == Nodetype.NAME:
        return [rosbags_message(v, element) for v in value]
    if element[0] == "string":
        return list(value)
    if element[0] == "byte" and len(value) and isinstance(value[0], bytes):
        value = b"".join(value)  # rclpy: a list of one-byte bytes objects
    dtype = {"bool": np.bool_, "char": np.uint8, "byte": np.int8}.get(element[0], element[0])
    if isinstance(value, (bytes, bytearray)):
        return np.frombuffer(value, dtype=dtype).copy()
    return np.array(value, dtype=dtype)


def deserialize(data: bytes, typename: str):
    """The message of ``typename`` encoded in CDR ``data``. Decoded by rosbags first whichever the backend, so
    that what is refused is the same with and without rclpy: rclpy's decoder accepts what rosbags refuses
    (a string that is not UTF-8 comes out with replacement characters)."""
    message = TYPESTORE.deserialize_cdr(data, typename)
    if BACKEND == "rclpy":
        return _rclpy_deserialize(bytes(data), message_class(typename))
    return message


def field_names(message) -> list[str]:
    """The field names of a message object, in definition order."""
    if BACKEND == "rclpy":
        return list(message.get_fields_and_field_types())
    return [f.name for f in dataclasses.fields(message)]


@cache
def schema_text(typename: str) -> str:
    """The ``ros2msg`` schema of ``typename``: its definition, then every dependency after a
    ``====`` separator line and ``MSG: pkg/Name``, as rosbag2 writes it to MCAP."""
    return TYPESTORE.generate_msgdef(typename, ros_version=2)[0]


@cache
def type_hash(typename: str) -> str:
    """The RIHS01 type-description hash of ``typename`` (what Jazzy's rosbag2 records per topic)."""
    return TYPESTORE.hash_rihs01(typename)


# ---------------------------------------------------------------------------- builders of common messages
def time(ns: int):
    """builtin_interfaces/Time from integer nanoseconds."""
    return new("builtin_interfaces/msg/Time", sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def header(ns: int, frame_id: str):
    return new("std_msgs/msg/Header", stamp=time(ns), frame_id=frame_id)


def point(x: float, y: float, z: float):
    return new("geometry_msgs/msg/Point", x=x, y=y, z=z)


def vector3(x: float, y: float, z: float):
    return new("geometry_msgs/msg/Vector3", x=x, y=y, z=z)


def color(r: float, g: float, b: float, a: float = 1.0):
    return new("std_msgs/msg/ColorRGBA", r=r, g=g, b=b, a=a)


def key_values(mapping: dict) -> list:
    """diagnostic_msgs/KeyValue list from a str -> str mapping."""
    return [new("diagnostic_msgs/msg/KeyValue", key=k, value=v) for k, v in mapping.items()]


def joint_state(header_msg, names: list[str], position=(), velocity=(), effort=()):
    return new("sensor_msgs/msg/JointState", header=header_msg, name=list(names), position=float64s(position),
               velocity=float64s(velocity), effort=float64s(effort))


def wrench_stamped(header_msg, force, torque=(0.0, 0.0, 0.0)):
    """geometry_msgs/WrenchStamped; ``force``, ``torque`` 3 numbers each."""
    return new("geometry_msgs/msg/WrenchStamped", header=header_msg,
               wrench=new("geometry_msgs/msg/Wrench", force=vector3(*map(float, force)),
                          torque=vector3(*map(float, torque))))


# rcl_interfaces/ParameterType: the type of each parameter value the node has, and the field that holds it
_PARAMETER_TYPES = {bool: (1, "bool_value"), int: (2, "integer_value"), float: (3, "double_value"),
                    str: (4, "string_value")}
_PARAMETER_FIELDS = dict(_PARAMETER_TYPES.values())


def _parameter_value(value):
    """rcl_interfaces/ParameterValue holding a bool, int, float or str (the array fields empty)."""
    kind, name = _PARAMETER_TYPES[type(value)]
    empty = (lambda dtype: []) if BACKEND == "rclpy" else (lambda dtype: np.zeros(0, dtype))
    values = {"bool_value": False, "integer_value": 0, "double_value": 0.0, "string_value": "", name: value}
    return new("rcl_interfaces/msg/ParameterValue", type=kind, **values, byte_array_value=empty(np.int8),
               bool_array_value=empty(bool), integer_array_value=empty(np.int64),
               double_array_value=empty(np.float64), string_array_value=[])


def parameter_event(ns: int, node: str, changed: dict):
    """rcl_interfaces/ParameterEvent stamped ``ns``: the ``changed`` parameters (name -> value) of ``node``
    (its fully qualified name)."""
    return new("rcl_interfaces/msg/ParameterEvent", stamp=time(ns), node=node, new_parameters=[],
               changed_parameters=[new("rcl_interfaces/msg/Parameter", name=k, value=_parameter_value(v))
                                   for k, v in changed.items()], deleted_parameters=[])


def parameter_changes(event) -> dict:
    """The changed parameters (name -> value) of a ParameterEvent (the inverse of :func:`parameter_event`);
    ValueError for a value of a type :func:`parameter_event` does not write."""
    out = {}
    for p in event.changed_parameters:
        if p.value.type not in _PARAMETER_FIELDS:
            raise ValueError(f"parameter {p.name!r}: value of ParameterType {p.value.type} (not bool, integer, "
                             f"double or string)")
        out[p.name] = getattr(p.value, _PARAMETER_FIELDS[p.value.type])
    return out
