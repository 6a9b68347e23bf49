"""CdrTemplate against rosbags' serialize_cdr, byte for byte: the independent reference of every byte the
log gets from the templates. References are built with the type store's classes directly, not with
``cdr.prototype``, and cover the padding cases (frame ids and names of every length mod 4, empty and
non-empty arrays, 1 to 300 poses), float32 and bool fields, fixed-size arrays, and float64 values whose
bits must survive (NaN payloads, -0.0, infinities, subnormals). The node's compiled encoder of a
publication (``PublicationCdr``) against the templates it replaces, byte for byte."""
import struct

import numpy as np
import pytest

from tensegrity_sim.ros.cdr import CdrTemplate, prototype
from tensegrity_sim.ros.messages import TYPESTORE
from tensegrity_sim.ros.publication import PublicationCdr, PublicationTemplates

STAMP = ("header.stamp.sec", "header.stamp.nanosec")


def new(typename, **fields):
    return TYPESTORE.types[typename](**fields)


def reference(message, typename) -> bytes:
    return bytes(TYPESTORE.serialize_cdr(message, typename))


def header(sec, nanosec, frame_id):
    return new("std_msgs/msg/Header", stamp=new("builtin_interfaces/msg/Time", sec=sec, nanosec=nanosec),
               frame_id=frame_id)


def awkward_floats(rng, shape) -> np.ndarray:
    """Random float64s with special values mixed in, among them a NaN with a payload."""
    x = rng.normal(size=shape) * 10.0 ** rng.integers(-300, 300, size=shape)
    special = np.array([0.0, -0.0, np.inf, -np.inf, 5e-324, -2.2250738585072014e-308,
                        struct.unpack("<d", struct.pack("<Q", 0x7FF8_0000_DEAD_BEEF))[0]])
    flat = x.reshape(-1)
    flat[rng.integers(0, flat.size, size=min(flat.size, 5))] = rng.choice(special, size=min(flat.size, 5))
    return x


FRAMES = ["", "w", "map", "world", "base_link", "ünïcode"]


@pytest.mark.parametrize("n", [0, 1, 2, 3, 7, 300])
@pytest.mark.parametrize("frame", FRAMES)
def test_pose_array(n, frame):
    rng = np.random.default_rng(n)
    template = CdrTemplate("geometry_msgs/msg/PoseArray",
                           {"header": {"frame_id": frame}, "poses": [{"orientation": {"w": 1.0}}] * n},
                           (*STAMP, "poses[].position"))
    for sec, nanosec in [(0, 0), (12, 345_678_901), (2**31 - 1, 999_999_999)]:
        x = awkward_floats(rng, (n, 3))
        q = new("geometry_msgs/msg/Quaternion", x=0.0, y=0.0, z=0.0, w=1.0)
        poses = [new("geometry_msgs/msg/Pose", position=new("geometry_msgs/msg/Point", x=a, y=b, z=c), orientation=q)
                 for a, b, c in x.tolist()]
        expected = reference(new("geometry_msgs/msg/PoseArray", header=header(sec, nanosec, frame), poses=poses),
                             "geometry_msgs/msg/PoseArray")
        assert template.encode(sec, nanosec, x) == expected


@pytest.mark.parametrize("n", [0, 1, 2, 5, 57, 300])
@pytest.mark.parametrize("frame", FRAMES[:5])
@pytest.mark.parametrize("filled", [("position", "velocity", "effort"), ("effort",), ("position",), ()])
def test_joint_state(n, frame, filled):
    """Names of lengths 1 to 8 (every padding before the next name and before the float64 arrays)."""
    rng = np.random.default_rng(len(frame) + n)
    names = [f"c{i}" + "x" * (i % 7) for i in range(n)]
    arrays = {f: awkward_floats(rng, n) for f in filled}
    empty = np.zeros(0)
    template = CdrTemplate("sensor_msgs/msg/JointState",
                           {"header": {"frame_id": frame}, "name": names, **{f: np.zeros(n) for f in filled}},
                           (*STAMP, *filled))
    expected = reference(new("sensor_msgs/msg/JointState", header=header(7, 8, frame), name=names,
                             **{f: arrays.get(f, empty) for f in ("position", "velocity", "effort")}),
                         "sensor_msgs/msg/JointState")
    assert template.encode(7, 8, *arrays.values()) == expected


def test_clock():
    template = CdrTemplate("rosgraph_msgs/msg/Clock", None, ("clock.sec", "clock.nanosec"))
    for sec, nanosec in [(0, 0), (1, 999_999_999), (2**31 - 1, 5)]:
        expected = reference(new("rosgraph_msgs/msg/Clock", clock=new("builtin_interfaces/msg/Time", sec=sec,
                                                                     nanosec=nanosec)), "rosgraph_msgs/msg/Clock")
        assert template.encode(sec, nanosec) == expected


@pytest.mark.parametrize("k", [0, 1, 4])
@pytest.mark.parametrize("ns", ["", "ab", "struts"])
def test_marker_with_float32_bool_and_nested_constants(k, ns):
    """A Marker: strings, int32s, a bool before the points, float32 colours, and constants after them."""
    rng = np.random.default_rng(k)
    points, colors, scale = rng.normal(size=(k, 3)), rng.uniform(size=(k, 4)), rng.uniform(size=3)
    template = CdrTemplate("visualization_msgs/msg/Marker", {
        "header": {"frame_id": "world"}, "ns": ns, "id": 3, "type": 5, "pose": {"orientation": {"w": 1.0}},
        "frame_locked": True, "points": [{}] * k, "colors": [{}] * k, "text": "label",
        "mesh_use_embedded_materials": True},
        (*STAMP, "scale", "points[]", "colors[]"))
    empty_header = header(0, 0, "")
    expected = reference(new(
        "visualization_msgs/msg/Marker", header=header(3, 4, "world"), ns=ns, id=3, type=5, action=0,
        pose=new("geometry_msgs/msg/Pose", position=new("geometry_msgs/msg/Point", x=0.0, y=0.0, z=0.0),
                 orientation=new("geometry_msgs/msg/Quaternion", x=0.0, y=0.0, z=0.0, w=1.0)),
        scale=new("geometry_msgs/msg/Vector3", x=scale[0], y=scale[1], z=scale[2]),
        color=new("std_msgs/msg/ColorRGBA", r=0.0, g=0.0, b=0.0, a=0.0),
        lifetime=new("builtin_interfaces/msg/Duration", sec=0, nanosec=0), frame_locked=True,
        points=[new("geometry_msgs/msg/Point", x=a, y=b, z=c) for a, b, c in points.tolist()],
        colors=[new("std_msgs/msg/ColorRGBA", r=r, g=g, b=b, a=a) for r, g, b, a in colors.tolist()],
        texture_resource="", texture=new("sensor_msgs/msg/CompressedImage", header=empty_header, format="",
                                         data=np.zeros(0, dtype=np.uint8)),
        uv_coordinates=[], text="label", mesh_resource="",
        mesh_file=new("visualization_msgs/msg/MeshFile", filename="", data=np.zeros(0, dtype=np.uint8)),
        mesh_use_embedded_materials=True), "visualization_msgs/msg/Marker")
    assert template.encode(3, 4, scale, points, colors) == expected


def marker(stamp, ns, points, colors=None):
    """A visualization_msgs/Marker with every other field zero or empty."""
    return new("visualization_msgs/msg/Marker", header=header(*stamp, "world"), ns=ns, id=0, type=0, action=0,
               pose=new("geometry_msgs/msg/Pose", position=new("geometry_msgs/msg/Point", x=0.0, y=0.0, z=0.0),
                        orientation=new("geometry_msgs/msg/Quaternion", x=0.0, y=0.0, z=0.0, w=0.0)),
               scale=new("geometry_msgs/msg/Vector3", x=0.0, y=0.0, z=0.0),
               color=new("std_msgs/msg/ColorRGBA", r=0.0, g=0.0, b=0.0, a=0.0),
               lifetime=new("builtin_interfaces/msg/Duration", sec=0, nanosec=0), frame_locked=False,
               points=[new("geometry_msgs/msg/Point", x=a, y=b, z=c) for a, b, c in points.tolist()],
               colors=[] if colors is None else [new("std_msgs/msg/ColorRGBA", r=r, g=g, b=b, a=a)
                                                 for r, g, b, a in colors.tolist()],
               texture_resource="", texture=new("sensor_msgs/msg/CompressedImage", header=header(0, 0, ""), format="",
                                                data=np.zeros(0, dtype=np.uint8)),
               uv_coordinates=[], text="", mesh_resource="",
               mesh_file=new("visualization_msgs/msg/MeshFile", filename="", data=np.zeros(0, dtype=np.uint8)),
               mesh_use_embedded_materials=False)


@pytest.mark.parametrize("counts", [(2, 5), (1, 0), (3, 1), (0, 4)])
def test_indexed_slots_in_markers_of_different_sizes(counts):
    """A MarkerArray whose markers have different point counts and namespace lengths, so that their
    numbers are not a fixed stride apart: slots by element index."""
    rng = np.random.default_rng(sum(counts))
    a, b = (rng.normal(size=(k, 3)) for k in counts)
    colors = rng.uniform(size=(counts[1], 4))
    template = CdrTemplate("visualization_msgs/msg/MarkerArray", {"markers": [
        {"header": {"frame_id": "world"}, "ns": "a", "points": [{}] * counts[0]},
        {"header": {"frame_id": "world"}, "ns": "cables", "points": [{}] * counts[1], "colors": [{}] * counts[1]}]},
        ("markers[0].header.stamp.sec", "markers[0].header.stamp.nanosec", "markers[0].points[]",
         "markers[1].header.stamp.sec", "markers[1].header.stamp.nanosec", "markers[1].points[]",
         "markers[1].colors[]"))
    expected = reference(new("visualization_msgs/msg/MarkerArray", markers=[
        marker((5, 6), "a", a), marker((7, 8), "cables", b, colors)]), "visualization_msgs/msg/MarkerArray")
    assert template.encode(5, 6, a, 7, 8, b, colors) == expected


MARKER_SLOTS = ("markers[0].header.stamp.sec", "markers[0].header.stamp.nanosec", "markers[0].points[]",
                "markers[1].header.stamp.sec", "markers[1].header.stamp.nanosec", "markers[1].points[]",
                "markers[1].colors[]", "markers[2].id")


def two_markers_and_a_deleted(frame: str, counts=(1, 1)) -> CdrTemplate:
    return CdrTemplate("visualization_msgs/msg/MarkerArray", {"markers": [
        {"header": {"frame_id": frame}, "ns": "a", "points": [{}] * counts[0]},
        {"header": {"frame_id": frame}, "ns": "cables", "points": [{}] * counts[1], "colors": [{}] * counts[1]},
        {"header": {"frame_id": frame}, "ns": "gone", "action": 2}]}, MARKER_SLOTS)


@pytest.mark.parametrize("frame", ["", "w", "wor", "world"])
@pytest.mark.parametrize("first, then", [((1, 1), (2, 5)), ((3, 4), (1, 1)), ((1, 1), (40, 17)), ((5, 2), (2, 9))])
def test_resized_markers_are_rosbags_bytes(frame, first, then):
    """A MarkerArray template resized (its points and colours), then resized again, against rosbags' bytes of
    the messages of those lengths: the padding after each sequence and the slots behind it follow."""
    rng = np.random.default_rng(sum(first) + 10 * sum(then) + len(frame))

    def expected(a, b, colors) -> bytes:
        markers = [marker((5, 6), "a", a), marker((7, 8), "cables", b, colors), marker((0, 0), "gone", a[:0])]
        for m in markers:
            m.header.frame_id = frame
        markers[2].action, markers[2].id = 2, 77
        return reference(new("visualization_msgs/msg/MarkerArray", markers=markers),
                         "visualization_msgs/msg/MarkerArray")

    base = template = two_markers_and_a_deleted(frame)
    for counts in (first, then):
        template = template.resized({"markers[0].points": counts[0], "markers[1].points": counts[1],
                                     "markers[1].colors": counts[1]})
        a, b = (awkward_floats(rng, (k, 3)) for k in counts)
        colors = rng.uniform(size=(counts[1], 4)).astype(np.float32)
        assert template.encode(5, 6, a, 7, 8, b, colors, 77) == expected(a, b, colors)
        assert template.place("markers[1].colors[]")[1] == (counts[1], 4)
    # resizing makes a new template: the one it came from still encodes its lengths
    a, b, colors = np.ones((1, 3)), np.full((1, 3), 2.0), np.full((1, 4), 0.5)
    assert base.encode(5, 6, a, 7, 8, b, colors, 77) == expected(a, b, colors)


@pytest.mark.parametrize("lengths, message", [
    ({"markers[0].points": 0}, "visualization_msgs/msg/MarkerArray: 'markers[0].points' (1 elements) cannot be "
                               "resized to 0"),
    ({"markers[2].points": 3}, "visualization_msgs/msg/MarkerArray: 'markers[2].points' (0 elements) cannot be "
                               "resized to 3"),
    ({"markers[0].text": 3}, "visualization_msgs/msg/MarkerArray: no sequence 'markers[0].text'"),
    ({"markers": 2}, "visualization_msgs/msg/MarkerArray: 'markers' (3 elements) cannot be resized to 2"),
])
def test_resizing_what_cannot_keep_its_padding_is_refused(lengths, message):
    """Only sequences of one or more fixed-size elements of a multiple of 8 bytes, to one or more: an empty
    sequence has no padding before its (absent) elements, and a Marker's size depends on its strings."""
    with pytest.raises(ValueError) as err:
        two_markers_and_a_deleted("world").resized(lengths)
    assert str(err.value).startswith(message)


def test_an_indexed_slot_inside_a_resized_sequence_is_refused():
    template = CdrTemplate("visualization_msgs/msg/Marker", {"points": [{}] * 2}, ("points[1].x",))
    with pytest.raises(ValueError, match=r"slot 'points\[1\]\.x' is inside 'points', which is resized"):
        template.resized({"points": 5})


def test_fixed_size_arrays_and_small_integers():
    """NavSatFix: an int8 and a uint16 before the float64s, a float64[9] array, a uint8 after it."""
    rng = np.random.default_rng(5)
    template = CdrTemplate("sensor_msgs/msg/NavSatFix", {
        "header": {"frame_id": "gps"}, "status": {"status": -1, "service": 3}, "position_covariance_type": 2},
        (*STAMP, "latitude", "altitude", "position_covariance"))
    lat, alt, cov = rng.normal(), rng.normal(), awkward_floats(rng, 9)
    expected = reference(new(
        "sensor_msgs/msg/NavSatFix", header=header(1, 2, "gps"),
        status=new("sensor_msgs/msg/NavSatStatus", status=-1, service=3), latitude=lat, longitude=0.0,
        altitude=alt, position_covariance=cov, position_covariance_type=2), "sensor_msgs/msg/NavSatFix")
    assert template.encode(1, 2, lat, alt, cov) == expected


def test_encoding_does_not_keep_the_values():
    """Every encode writes all slots anew and returns its own bytes."""
    template = CdrTemplate("sensor_msgs/msg/JointState", {"name": ["a", "b"], "effort": np.zeros(2)},
                           (*STAMP, "effort"))
    first = template.encode(1, 2, np.array([1.0, 2.0]))
    second = template.encode(3, 4, np.array([5.0, 6.0]))
    assert first != second and template.encode(1, 2, np.array([1.0, 2.0])) == first


def test_prototype_defaults():
    m = prototype("visualization_msgs/msg/Marker", {"ns": "x", "points": [{"y": 2.0}]})
    assert (m.ns, m.id, m.frame_locked, m.header.frame_id, m.pose.orientation.w) == ("x", 0, False, "", 0.0)
    assert [(p.x, p.y, p.z) for p in m.points] == [(0.0, 2.0, 0.0)] and m.colors == []
    assert m.texture.data.dtype == np.uint8 and m.texture.data.size == 0
    fix = prototype("sensor_msgs/msg/NavSatFix")
    assert fix.position_covariance.shape == (9,) and not fix.position_covariance.any()


@pytest.mark.parametrize("typename, fields, slots, message", [
    ("geometry_msgs/msg/PoseArray", {"frame": "x"}, (), "geometry_msgs/msg/PoseArray has no field 'frame' "
                                                         "(fields: header, poses)"),
    ("geometry_msgs/msg/PoseArray", None, ("header.stamp.secs",), "geometry_msgs/msg/PoseArray: slot "
                                                                 "'header.stamp.secs': no field 'secs' there"),
    ("geometry_msgs/msg/PoseArray", None, ("poses.position",), "geometry_msgs/msg/PoseArray: slot "
                                                              "'poses.position': no field 'position' there"),
    ("geometry_msgs/msg/PoseArray", None, ("header[]",), "geometry_msgs/msg/PoseArray: slot 'header[]': "
                                                         "'header' is not a sequence or array"),
    ("geometry_msgs/msg/PoseArray", None, ("header[0].stamp",),
     "geometry_msgs/msg/PoseArray: slot 'header[0].stamp': 'header' is not a sequence or array"),
    ("geometry_msgs/msg/PoseArray", None, ("header.frame_id",), "geometry_msgs/msg/PoseArray: slot "
                                                               "'header.frame_id' holds a string (slots hold numbers)"),
    ("geometry_msgs/msg/PoseArray", None, ("header.stamp",), "geometry_msgs/msg/PoseArray: slot 'header.stamp' "
                                                            "mixes int32 and uint32"),
    ("sensor_msgs/msg/JointState", {"name": ["a"]}, ("name",), "sensor_msgs/msg/JointState: slot 'name' holds "
                                                              "a string (slots hold numbers)"),
])
def test_bad_templates_are_refused(typename, fields, slots, message):
    with pytest.raises(ValueError) as err:
        CdrTemplate(typename, fields, slots)
    assert str(err.value) == message


def test_wrong_number_of_values_is_refused():
    template = CdrTemplate("rosgraph_msgs/msg/Clock", None, ("clock.sec", "clock.nanosec"))
    with pytest.raises(ValueError):
        template.encode(1)


def test_a_slot_must_be_evenly_spaced():
    """Markers whose namespaces differ in length: their ids are not a fixed stride apart."""
    with pytest.raises(ValueError) as err:
        CdrTemplate("visualization_msgs/msg/MarkerArray", {"markers": [{"ns": "a"}, {"ns": "a" * 20}, {"ns": "ab"}]},
                    ("markers[].id",))
    assert str(err.value) == "visualization_msgs/msg/MarkerArray: the numbers of slot 'markers[].id' are not " \
                             "evenly spaced"


def test_a_walk_that_disagrees_with_rosbags_is_refused():
    class LongerBytes:
        """The type store, but its serialiser writes four bytes more than the CDR walk expects."""

        def __getattr__(self, name):
            return getattr(TYPESTORE, name)

        def serialize_cdr(self, message, typename):
            return bytes(TYPESTORE.serialize_cdr(message, typename)) + bytes(4)

    with pytest.raises(ValueError) as err:
        CdrTemplate("rosgraph_msgs/msg/Clock", None, ("clock.sec",), store=LongerBytes())
    assert str(err.value) == "rosgraph_msgs/msg/Clock: the CDR walk ends at byte 12, rosbags' bytes at 16"


@pytest.mark.parametrize("frame", ["", "w", "map", "worl", "world", "base_l", "base_li", "base_link", "ünïcode"])
@pytest.mark.parametrize("n_nodes, n_cables", [(2, 1), (3, 0), (12, 24), (41, 100)])
def test_publication_in_one_pass_is_the_templates_bytes(frame, n_nodes, n_cables):
    """``PublicationCdr`` (one compiled pass over one buffer) writes the very bytes of the four templates
    filled in turn (``PublicationTemplates``), whatever the padding: frame ids of every length mod 8,
    cable names of lengths 1 to 8, no cables; stamps up to the largest int32; special floats kept."""
    rng = np.random.default_rng(n_nodes + len(frame))
    names = [f"c{i}" + "x" * (i % 8) for i in range(n_cables)]
    ends = rng.integers(0, n_nodes, size=(n_cables, 2))
    ends[:, 1] = (ends[:, 0] + 1 + rng.integers(0, n_nodes - 1, size=n_cables)) % n_nodes  # two distinct nodes
    weights = np.where(rng.random((n_cables, 2)) < 0.5, 0.0, rng.random((n_cables, 2)))   # some along a "strut"
    nodes = np.stack([ends, (ends + 1) % n_nodes], axis=2)
    nodes[..., 1] = np.where(weights > 0, nodes[..., 1], nodes[..., 0])
    reference = PublicationTemplates(frame, n_nodes, names, nodes, weights)
    fast = PublicationCdr(reference)
    for ns in (0, 1_234_567_891, (2**31 - 1) * 10**9 + 999_999_999):
        x, v = rng.normal(size=(n_nodes, 3)), rng.normal(size=(n_nodes, 3))
        tensions, impulses = awkward_floats(rng, n_cables), awkward_floats(rng, n_cables)
        expected = reference.encode(ns, x, v, tensions, impulses)
        assert fast.encode(ns, x, v, tensions, impulses) == expected
    with pytest.raises(ValueError, match="do not fit"):
        fast.encode(2**31 * 10**9, x, v, tensions, impulses)
    with pytest.raises(ValueError, match="other sizes"):
        fast.encode(0, x[:-1], v[:-1], tensions, impulses)
