"""CDR bytes of the node's high-rate outputs, written straight from numpy arrays.

Serialising a message object with rosbags (``TYPESTORE.serialize_cdr``) walks it field by field in
Python: a ``PoseArray`` costs one ``Pose`` object to build and to encode per node, a ``JointState`` one
string per cable, tens of µs per message. But from one publication to the next only the numbers change:
the frame id, the cable names, the array lengths, the identity quaternions and so all the padding stay.
A :class:`CdrTemplate` therefore serialises one prototype message with rosbags, once, and keeps where
the changing numbers (its *slots*) sit in those bytes; encoding a message is then writing the numbers
into the slots (numpy assignments into views of a preallocated buffer) and copying the buffer.

Where the slots sit is not written down here: it is found by walking the prototype along the type
store's field definitions (the definitions rosbags serialises by) with the rules of plain CDR (XCDR1),
little endian, as ROS 2 and rosbag2 carry it:

* a 4-byte encapsulation header (``00 01 00 00``: CDR_LE), then the body; alignment is relative to the
  start of the body;
* every primitive aligned to its own size (bool, byte, char, int8, uint8: 1; int16, uint16: 2; int32,
  uint32, float32: 4; int64, uint64, float64: 8);
* a string: uint32 length including the terminating NUL, the UTF-8 bytes, the NUL;
* a sequence: uint32 element count, then the elements (an empty sequence has no padding after its
  count); a fixed-size array: the elements alone; a nested message: its fields in order.

The walk must end exactly where rosbags' bytes end, or the template refuses to be built; the tests
compare templates with ``serialize_cdr`` byte for byte over varied messages. A transport that sends raw
CDR (DDS, rclpy's ``publish`` of bytes) can use the same bytes the log gets.
"""
from __future__ import annotations

import re
from typing import Mapping, Sequence

import numpy as np
from rosbags.interfaces import Nodetype

from .messages import TYPESTORE

__all__ = ["CdrTemplate", "prototype"]

# little-endian numpy dtype of every fixed-size ROS primitive (float128 has none in CDR)
_DTYPES = {"bool": "?", "byte": "u1", "char": "u1", "int8": "i1", "uint8": "u1", "int16": "<i2",
           "uint16": "<u2", "int32": "<i4", "uint32": "<u4", "int64": "<i8", "uint64": "<u8",
           "float32": "<f4", "float64": "<f8"}
_SIZES = {kind: np.dtype(dtype).itemsize for kind, dtype in _DTYPES.items()}
_HEADER = 4  # bytes of the encapsulation header before the body


def prototype(typename: str, fields: Mapping | None = None, store=TYPESTORE):
    """A message of ``typename`` (a class of ``store``) with every field zero, False, empty or all zero
    but those in ``fields``: a value, or for a nested message a mapping of its fields, for a sequence or
    array of messages a list of such mappings. Raises ``ValueError`` naming a field the type lacks."""
    given = dict(fields or {})
    names = [name for name, _ in store.fielddefs[typename][1]]
    unknown = sorted(set(given) - set(names))
    if unknown:
        raise ValueError(f"{typename} has no field {unknown[0]!r} (fields: {', '.join(names)})")
    return store.types[typename](**{name: _value(desc, given.get(name), store)
                                    for name, desc in store.fielddefs[typename][1]})


def _value(desc, given, store):
    """The value of one field of description ``desc`` for :func:`prototype` (None: the zero value)."""
    node, detail = desc
    if node == Nodetype.BASE:
        kind = detail[0]
        if given is not None:
            return given
        return "" if kind == "string" else False if kind == "bool" else 0.0 if kind.startswith("float") else 0
    if node == Nodetype.NAME:
        return prototype(detail, given, store)
    (element_node, element), count = detail
    if node == Nodetype.ARRAY and given is None:
        given = [None] * count if element_node == Nodetype.NAME or element[0] == "string" else np.zeros(count)
    if element_node == Nodetype.NAME:
        return [prototype(element, item, store) for item in given or []]
    if element[0] == "string":
        return list(given or [])
    return np.asarray(given if given is not None else [], dtype=_DTYPES[element[0]]).reshape(-1)


class CdrTemplate:
    """The CDR bytes (with the encapsulation header) of messages of type ``typename`` that differ from
    ``prototype(typename, fields)`` only in the numbers at ``slots``.

    slots: field paths, dotted (``"header.stamp.sec"``), with ``[]`` after a sequence or array field for
    each of its elements (``"poses[].position"``) or ``[i]`` for element i (``"markers[2].points[]"``).
    A slot holds numbers of one primitive type, and
    :meth:`encode` takes one array-like per slot, in order, shaped as the slot: ``()`` for a primitive
    field, ``(k,)`` for a sequence or array of k primitives or a message of k primitive fields, and a
    leading axis of one entry per element for a path with ``[]`` (``"poses[].position"`` of n poses:
    ``(n, 3)``). The lengths of sequences are those of the prototype: they are constants too.

    Raises ``ValueError`` for an unknown field, a slot that holds a string or mixes types, or (a bug in
    the walk, never expected) a layout that disagrees with rosbags' bytes.
    """

    def __init__(self, typename: str, fields: Mapping | None, slots: Sequence[str], store=TYPESTORE):
        self.typename = typename
        self.slots = tuple(slots)
        message = prototype(typename, fields, store)
        self._store = store
        self._buffer = bytearray(store.serialize_cdr(message, typename))
        for slot in self.slots:
            _resolve(typename, slot, store)
        # the walk names element i of a sequence "name[i]"; a slot's "[]" stands for any i. One pattern
        # for all slots (group s<k>: slot k; the first slot that matches wins), tried at every field the walk
        # visits: one regex call per field instead of one per slot (a MarkerArray template's walk visits
        # ~600 fields, and building one sat in the step loop of the first publication of each new shape)
        any_index = [re.escape(slot).replace(r"\[\]", r"\[\d+\]") for slot in self.slots]
        self._pattern = re.compile("|".join(f"(?P<s{k}>{p})" for k, p in enumerate(any_index)) or "(?!)")
        # slot -> one (field description, [(body offset, primitive), ...]) per place the path matched
        self._matches: dict[str, list[tuple[object, list[tuple[int, str]]]]] = {s: [] for s in self.slots}
        # sequence path -> (body offset of its count, element description, element count, body offset after
        # the elements), for resized
        self._sequences: dict[str, tuple[int, object, int, int]] = {}
        end = self._walk((Nodetype.NAME, typename), message, 0, "", None)
        if _HEADER + end != len(self._buffer):
            raise ValueError(f"{typename}: the CDR walk ends at byte {_HEADER + end}, rosbags' bytes at "
                             f"{len(self._buffer)}")
        self._places: dict[str, tuple[int, tuple[int, ...], tuple[int, ...], np.dtype]] = {}
        self._views = [self._view(slot) for slot in self.slots]

    def encode(self, *values) -> bytes:
        """The CDR bytes of the prototype with ``values`` (one per slot, in order) in the slots; the
        numbers are written as they are (float64 bit for bit)."""
        for view, value in zip(self._views, values, strict=True):
            if view is not None:
                view[...] = value
        return bytes(self._buffer)

    def place(self, slot: str) -> tuple[int, tuple[int, ...], tuple[int, ...], np.dtype] | None:
        """Where :meth:`encode` writes the numbers of ``slot`` in its bytes: (byte offset of the first, the
        slot's shape, strides in bytes along it, dtype), or None for a slot with no numbers; for an
        encoder that writes them itself (:class:`~.publication.PublicationCdr`). KeyError for a slot the
        template does not have."""
        if slot not in self._places and slot not in self.slots:
            raise KeyError(f"{self.typename}: no slot {slot!r} (slots: {', '.join(self.slots)})")
        return self._places.get(slot)

    def resized(self, lengths: Mapping[str, int]) -> "CdrTemplate":
        """This template with the sequences named in ``lengths`` (paths without brackets, as
        ``"markers[2].points"``) holding that many elements (>= 1), the new ones copies of the last: a few
        byte copies, not a new walk of the message (which costs ~0.1 ms per hundred fields).

        It holds for a sequence of at least one element of a fixed size that is a multiple of 8 bytes
        (``geometry_msgs/Point``: 24, ``std_msgs/ColorRGBA``: 16): whatever follows it moves by a multiple of
        every CDR alignment, so its padding stays, and the padding before the first element stays with
        it. A ``[]`` slot over such a sequence gets its new length; slots after it move with it. Raises
        ``ValueError`` for any other sequence, a length below 1 or an indexed slot inside the sequence."""
        inserts = []   # (body offset after a sequence's elements, elements added (< 0: removed), their size)
        counts = []    # (body offset of a count, its new value)
        for path, length in lengths.items():
            if path not in self._sequences:
                raise ValueError(f"{self.typename}: no sequence {path!r}")
            count, element, n, end = self._sequences[path]
            size = _fixed_size(element, self._store)
            if n < 1 or length < 1 or size is None or size % 8:
                raise ValueError(f"{self.typename}: {path!r} ({n} elements) cannot be resized to {length}: "
                                 "only sequences of one or more fixed-size elements of a multiple of 8 bytes, "
                                 "to one or more")
            inserts.append((end, length - n, size))
            counts.append((count, length))
        inserts.sort()
        old = self._buffer
        pieces, at = [], 0
        for end, extra, size in inserts:   # up to the end of the elements kept, then the copies of the last
            pieces += [old[at:_HEADER + end + min(extra, 0) * size], old[_HEADER + end - size:_HEADER + end] * extra]
            at = _HEADER + end
        pieces.append(old[at:])

        def moved(offset: int) -> int:
            """The body offset of what sat at body offset ``offset`` before the resizing."""
            return offset + sum(extra * size for end, extra, size in inserts if end <= offset)

        out = object.__new__(CdrTemplate)
        out.typename, out.slots, out._store = self.typename, self.slots, self._store
        out._buffer = bytearray(b"".join(pieces))
        for count, length in counts:
            out._buffer[_HEADER + moved(count):_HEADER + moved(count) + 4] = length.to_bytes(4, "little")
        out._sequences = {p: (moved(c), e, lengths.get(p, n), moved(end))
                          for p, (c, e, n, end) in self._sequences.items()}
        out._places, out._views = {}, []
        for slot in self.slots:
            place = self._places.get(slot)
            if place is None:
                out._views.append(None)
                continue
            offset, shape, strides, dtype = place
            body = offset - _HEADER
            inside = [(p, n) for p, (c, e, n, end) in self._sequences.items()
                      if p in lengths and c < body < end]
            if inside:
                path, n = inside[0]
                if slot != f"{path}[]" and not slot.startswith(f"{path}[]."):
                    raise ValueError(f"{self.typename}: slot {slot!r} is inside {path!r}, which is resized: "
                                     "only its [] slots can follow")
                shape = (lengths[path],) + shape[1:]
            place = (_HEADER + moved(body), shape, strides, dtype)
            out._places[slot] = place
            out._views.append(np.ndarray(shape, dtype, buffer=out._buffer, offset=place[0], strides=strides))
        return out

    # ---------------------------------------------------------------- layout
    def _walk(self, desc, value, pos: int, path: str, match: list | None) -> int:
        """The body offset after ``value`` (a field of description ``desc``) written at ``pos``; the
        (offset, primitive) of every primitive under a slot path go to that slot's matches."""
        if match is None:
            found = self._pattern.fullmatch(path)
            if found is not None:
                match = []
                self._matches[self.slots[int(found.lastgroup[1:])]].append((desc, match))
        node, detail = desc
        if node == Nodetype.BASE:
            kind = detail[0]
            if kind == "string":
                return _align(pos, 4) + 4 + len(value.encode()) + 1
            size = _SIZES[kind]
            pos = _align(pos, size)
            if match is not None:
                match.append((pos, kind))
            return pos + size
        if node == Nodetype.NAME:
            for name, field_desc in self._store.fielddefs[detail][1]:
                pos = self._walk(field_desc, getattr(value, name), pos, f"{path}.{name}" if path else name, match)
            return pos
        element, _ = detail
        if node == Nodetype.SEQUENCE:
            pos = _align(pos, 4) + 4
            count = pos - 4
        for i, item in enumerate(value):
            pos = self._walk(element, item, pos, f"{path}[{i}]", match)
        if node == Nodetype.SEQUENCE:
            self._sequences[path] = (count, element, len(value), pos)
        return pos

    def _view(self, slot: str) -> np.ndarray | None:
        """A view of the buffer at the slot's numbers, shaped as :meth:`encode` takes them; None for a
        slot with no numbers (an empty sequence: nothing to write)."""
        matches = self._matches[slot]
        leaves = [leaf for _, match in matches for leaf in match]
        if not leaves:
            return None
        kinds = sorted({kind for _, kind in leaves})
        if len(kinds) > 1:
            raise ValueError(f"{self.typename}: slot {slot!r} mixes {' and '.join(kinds)}")
        dtype = np.dtype(_DTYPES[kinds[0]])
        per = len(matches[0][1])
        first = leaves[0][0]
        stride = matches[1][1][0][0] - first if len(matches) > 1 else per * dtype.itemsize
        each = "[]" in slot                                  # a leading axis: one entry per element
        inner = matches[0][0][0] != Nodetype.BASE            # an axis over the numbers of one match
        shape = ((len(matches),) if each else ()) + ((per,) if inner else ())
        strides = ((stride,) if each else ()) + ((dtype.itemsize,) if inner else ())
        expected = [first + m * stride + j * dtype.itemsize for m in range(len(matches)) for j in range(per)]
        if any(len(match) != per for _, match in matches) or [p for p, _ in leaves] != expected:
            raise ValueError(f"{self.typename}: the numbers of slot {slot!r} are not evenly spaced")
        self._places[slot] = (_HEADER + first, shape, strides, dtype)
        return np.ndarray(shape, dtype, buffer=self._buffer, offset=_HEADER + first, strides=strides)


def _fixed_size(desc, store) -> int | None:
    """The CDR size in bytes of a field of description ``desc`` if every value of it has that size and no
    padding inside it depends on where it starts (primitives, messages of them laid out without gaps,
    fixed-size arrays of those); else None."""
    node, detail = desc
    if node == Nodetype.BASE:
        return _SIZES.get(detail[0])
    if node == Nodetype.ARRAY:
        size = _fixed_size(detail[0], store)
        return None if size is None else size * detail[1]
    if node != Nodetype.NAME:
        return None
    total = 0
    for _, field in store.fielddefs[detail][1]:
        size = _fixed_size(field, store)
        if size is None or total % _alignment(field, store):
            return None
        total += size
    return total


def _alignment(desc, store) -> int:
    """The CDR alignment of a fixed-size field: its largest primitive's size."""
    node, detail = desc
    if node == Nodetype.BASE:
        return _SIZES[detail[0]]
    if node == Nodetype.ARRAY:
        return _alignment(detail[0], store)
    return max(_alignment(field, store) for _, field in store.fielddefs[detail][1])


def _align(pos: int, size: int) -> int:
    return (pos + size - 1) & -size


def _resolve(typename: str, path: str, store) -> None:
    """Check that ``path`` names a field of ``typename`` (``[]`` or ``[i]`` only after sequences and
    arrays) that holds no string."""
    desc = (Nodetype.NAME, typename)
    for part in path.split("."):
        name, brackets = re.fullmatch(r"(.*?)(\[\d*\])?", part).groups()
        fields = dict(store.fielddefs[desc[1]][1]) if desc[0] == Nodetype.NAME else {}
        if name not in fields:
            raise ValueError(f"{typename}: slot {path!r}: no field {name!r} there")
        desc = fields[name]
        if brackets:
            if desc[0] not in (Nodetype.SEQUENCE, Nodetype.ARRAY):
                raise ValueError(f"{typename}: slot {path!r}: {name!r} is not a sequence or array")
            desc = desc[1][0]
    if _holds_string(desc, store):
        raise ValueError(f"{typename}: slot {path!r} holds a string (slots hold numbers)")


def _holds_string(desc, store) -> bool:
    node, detail = desc
    if node == Nodetype.BASE:
        return detail[0] == "string"
    if node == Nodetype.NAME:
        return any(_holds_string(d, store) for _, d in store.fielddefs[detail][1])
    return _holds_string(detail[0], store)
