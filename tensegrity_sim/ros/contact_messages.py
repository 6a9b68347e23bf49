"""``~/contacts`` messages (diagnostic_msgs/DiagnosticArray, ``msg_docs/contacts.md``): contact events
written as key/value strings that give back every float64 bit, and read back."""
from __future__ import annotations

import json

import numpy as np

from ..results import ContactEvent
from . import messages as M

__all__ = ["encode_contacts", "decode_contacts"]


def encode_contacts(events: list[ContactEvent], header):
    """``~/contacts`` (diagnostic_msgs/DiagnosticArray): one ``DiagnosticStatus`` per event, in time order.

    ``name`` = ``"contact <member_a> <member_b>"``, ``message`` = kind, ``level`` = OK, and ``values``
    (key/value strings, numbers written so that ``float()`` / ``json.loads`` give back the exact float64):
    ``kind`` (begin|end), ``member_a``, ``member_b``, ``time`` (s), ``point_a``, ``point_b`` ([x, y, z] m),
    ``normal`` ([x, y, z], unit, a to b), ``distance`` (m, negative = penetration), ``normal_impulse``
    (N*s) and ``tangential_impulse`` ([x, y, z] N*s): the contact's impulses over the event's step (a
    ground contact's landing impulse; zero for contacts that are only detected).
    """
    status = []
    for e in events:
        values = {
            "kind": e.kind, "member_a": e.members[0], "member_b": e.members[1], "time": repr(float(e.time)),
            "point_a": json.dumps(np.asarray(e.point_a, dtype=float).tolist()),
            "point_b": json.dumps(np.asarray(e.point_b, dtype=float).tolist()),
            "normal": json.dumps(np.asarray(e.normal, dtype=float).tolist()),
            "distance": repr(float(e.distance)),
            "normal_impulse": repr(float(e.normal_impulse)),
            "tangential_impulse": json.dumps(np.asarray(e.tangential_impulse, dtype=float).tolist()),
        }
        status.append(M.new("diagnostic_msgs/msg/DiagnosticStatus", level=M.byte(0),
                            name=f"contact {e.members[0]} {e.members[1]}", message=e.kind, hardware_id="",
                            values=M.key_values(values)))
    return M.new("diagnostic_msgs/msg/DiagnosticArray", header=header, status=status)


def decode_contacts(message) -> list[ContactEvent]:
    """The contact events of a ``~/contacts`` message (the inverse of :func:`encode_contacts`)."""
    out = []
    for status in message.status:
        v = {kv.key: kv.value for kv in status.values}
        out.append(ContactEvent(kind=v["kind"], members=(v["member_a"], v["member_b"]), time=float(v["time"]),
                                point_a=np.array(json.loads(v["point_a"])),
                                point_b=np.array(json.loads(v["point_b"])),
                                normal=np.array(json.loads(v["normal"])), distance=float(v["distance"]),
                                # absent from logs written before the ground existed
                                normal_impulse=float(v.get("normal_impulse", 0.0)),
                                tangential_impulse=np.array(json.loads(v.get("tangential_impulse", "[0, 0, 0]")))))
    return out
