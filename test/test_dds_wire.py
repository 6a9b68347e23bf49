"""The DDS layer against ROS 2's wire conventions: generated types, names, hashes, QoS, discovery,
and samples decoded in another process by two independent CDR implementations (rosbags and
cyclonedds' own)."""
import json
import re

import numpy as np
import pytest

from dds_child import JOINTS, POSES, joint_state, pose_array, random_domain, spawn
from ros_helpers import random_message
from tensegrity_sim.ros.dds import (MAX_DOMAIN_ID, Participant, QosProfile, check_domain_id, cyclone_config,
                                    dds_topic_name, dds_type, ros_peer_settings)
from tensegrity_sim.ros import messages as M
from tensegrity_sim.ros.messages import TYPESTORE

CHILD = "test/dds_child.py"


# --------------------------------------------------------------------------- generated types
def test_type_names_follow_rosidl_and_structs_are_final_and_keyless():
    pose_array_type = dds_type("geometry_msgs/msg/PoseArray")
    assert pose_array_type.dds_name == "geometry_msgs::msg::dds_::PoseArray_"
    idl = pose_array_type.idl
    idl.__idl__.populate()
    assert idl.__idl__.keyless
    assert idl.__idl_annotations__["extensibility"] == "final"
    # Nested types are generated alike, under their own ROS names.
    header = dds_type("std_msgs/msg/Header").idl
    assert header.__idl_typename__ == "std_msgs::msg::dds_::Header_"
    assert idl.__annotations__["header"] is header
    assert dds_topic_name("/tensegrity_sim/node_poses") == "rt/tensegrity_sim/node_poses"


def test_type_hashes_are_the_ones_a_jazzy_system_reports():
    # Published by ROS 2 Jazzy itself (`ros2 topic info -v`, rosidl-generated type descriptions).
    assert dds_type("sensor_msgs/msg/JointState").type_hash == \
        "RIHS01_a13ee3a330e346c9d87b5aa18d24e11690752bd33a0350f11c5882bc9179260e"
    assert dds_type("std_msgs/msg/String").type_hash == \
        "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"
    assert dds_type("std_msgs/msg/String").user_data == \
        b"typehash=RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18;"


def _same_content(ours, theirs, where):
    """rosbags' decoded message against cyclonedds' decoded struct, field by field."""
    if hasattr(ours, "__msgtype__"):
        for name in TYPESTORE.fielddefs[ours.__msgtype__][1]:
            _same_content(getattr(ours, name[0]), getattr(theirs, name[0]), f"{where}.{name[0]}")
    elif isinstance(ours, (list, np.ndarray)) and len(ours) and hasattr(ours[0], "__msgtype__"):
        assert len(ours) == len(theirs), where
        for k, (a, b) in enumerate(zip(ours, theirs)):
            _same_content(a, b, f"{where}[{k}]")
    elif isinstance(ours, (list, np.ndarray)):
        if isinstance(theirs, bytes):  # cyclonedds hands octet and uint8 arrays back as bytes
            theirs = np.frombuffer(theirs, dtype=np.uint8)
        assert np.array_equal(np.asarray(ours), np.asarray(theirs)), where
    else:
        assert ours == theirs and type(ours) is type(theirs), f"{where}: {ours!r} != {theirs!r}"


@pytest.mark.parametrize("seed", [0, 1])
def test_every_jazzy_message_type_decodes_alike_in_rosbags_and_cyclonedds(seed):
    """For each of the Jazzy store's message types, random content serialized by rosbags is decoded
    by cyclonedds through the generated type to the same values and re-serialized to the same bytes:
    the generated layouts are the ROS layouts (a float read as an int, a missing or reordered field,
    a wrong bound would all show)."""
    rng = np.random.default_rng(seed)
    assert len(TYPESTORE.fielddefs) > 150
    for msgtype in sorted(TYPESTORE.fielddefs):
        message = random_message(msgtype, rng)
        data = bytes(TYPESTORE.serialize_cdr(message, msgtype))
        theirs = dds_type(msgtype).idl.deserialize(data)
        _same_content(message, theirs, msgtype)
        assert theirs.serialize() == data, msgtype  # XCDR1, little endian, same header


def test_unknown_types_and_bad_topic_names_are_refused():
    with pytest.raises(ValueError, match="'tensegrity_msgs/msg/Nope' is not defined"):
        dds_type("tensegrity_msgs/msg/Nope")
    for bad in ["relative/name", "/a//b", "/1x", "", "/with space"]:
        with pytest.raises(ValueError, match="fully qualified ROS name"):
            dds_topic_name(bad)


# --------------------------------------------------------------------------- configuration
def test_loopback_configuration_discovers_by_unicast_on_127_0_0_1():
    xml = cyclone_config("lo")
    assert '<NetworkInterface name="lo"/>' in xml
    assert "<AllowMulticast>false</AllowMulticast>" in xml
    assert '<Peer address="127.0.0.1"/>' in xml and "<ParticipantIndex>auto</ParticipantIndex>" in xml
    assert "Peer" in cyclone_config("127.0.0.1") and 'address="127.0.0.1"' in cyclone_config("127.0.0.1")
    assert "Interfaces" not in cyclone_config("auto")
    # what the ROS side sets to find it (the serve banner says it): only on a loopback
    assert ros_peer_settings("lo", 7) == ros_peer_settings("127.0.0.1", 7) == "ROS_DOMAIN_ID=7 ROS_STATIC_PEERS=127.0.0.1"
    assert ros_peer_settings("auto", 7) is None


def test_bad_interface_and_domain_are_refused_with_the_reason():
    with pytest.raises(ValueError, match="no network interface named 'nonexistent0'"):
        cyclone_config("nonexistent0")
    with pytest.raises(ValueError, match=rf"domain_id must be a whole number in \[0, {MAX_DOMAIN_ID}\], got 233"):
        check_domain_id(233)
    for bad in [-1, 1.5, True, "3"]:
        with pytest.raises(ValueError, match="domain_id"):
            check_domain_id(bad)
    with pytest.raises(ValueError, match="depth must be a whole number >= 1, got 0"):
        QosProfile(depth=0)
    with pytest.raises(ValueError, match="no network interface named 'nonexistent0'"):
        Participant(domain_id=random_domain(), interface="nonexistent0")


def test_participants_of_one_process_share_its_domain():
    """Cyclone configures a domain once per process: a second participant joins it (and they talk);
    another configuration of the same domain is refused while it is in use; the last one out deletes it."""
    domain = random_domain()
    with Participant(domain_id=domain) as a, Participant(domain_id=domain) as b:
        writer = a.writer("/shared", "std_msgs/msg/String")
        reader = b.reader("/shared", "std_msgs/msg/String")
        while not writer.matched:
            b.wait(0.01)
        writer.write(M.new("std_msgs/msg/String", data="hello"))
        assert b.wait(5.0)
        assert [m.data for m in reader.take_messages()[0]] == ["hello"]
        with pytest.raises(ValueError, match=f"domain {domain} is already in use in this process over interface "
                                             "'lo', not '127.0.0.1'"):
            Participant(domain_id=domain, interface="127.0.0.1")
    with Participant(domain_id=domain, interface="127.0.0.1") as c:  # free again: any configuration
        assert c.domain_id == domain


# --------------------------------------------------------------------------- across processes
def test_a_ros_graph_sees_ros_names_types_hashes_qos_and_the_node():
    """What a ROS 2 machine's graph learns from discovery, read by another process."""
    domain = random_domain()
    with spawn(CHILD, "observe", str(domain), "4") as observer:
        with Participant(domain_id=domain, node_name="wire_test", namespace="/probe") as p:
            poses = p.writer("/probe/node_poses", "geometry_msgs/msg/PoseArray")
            clock = p.writer("/clock", "rosgraph_msgs/msg/Clock", QosProfile(reliable=False, depth=1))
            command = p.reader("/probe/cable_rest_lengths", "sensor_msgs/msg/JointState")
            out, err = observer.communicate(timeout=20)
            guids = {"poses": poses.guid.hex(), "clock": clock.guid.hex(), "command": command.guid.hex()}
            participant = p.guid.hex()
    assert observer.returncode == 0, err
    seen = [json.loads(line) for line in out.splitlines()]
    endpoints = {e["guid"]: e for e in seen if e["kind"] in ("publication", "subscription")}
    assert endpoints[guids["poses"]] == {
        "kind": "publication", "guid": guids["poses"], "topic": "rt/probe/node_poses",
        "type": "geometry_msgs::msg::dds_::PoseArray_",
        "user_data": f"typehash={TYPESTORE.hash_rihs01('geometry_msgs/msg/PoseArray')};",
        "reliable": True, "transient_local": False, "depth": 10, "xcdr1_only": True}
    assert endpoints[guids["clock"]]["topic"] == "rt/clock"
    assert endpoints[guids["clock"]]["type"] == "rosgraph_msgs::msg::dds_::Clock_"
    assert not endpoints[guids["clock"]]["reliable"] and endpoints[guids["clock"]]["depth"] == 1
    assert endpoints[guids["command"]]["kind"] == "subscription"
    assert endpoints[guids["command"]]["type"] == "sensor_msgs::msg::dds_::JointState_"
    assert re.fullmatch(r"typehash=RIHS01_[0-9a-f]{64};", endpoints[guids["command"]]["user_data"])
    # The node, on ros_discovery_info: its gids are the GUIDs discovery reported.
    announcement = [e for e in seen if e["kind"] == "node"][-1]
    assert announcement["participant"] == participant
    assert announcement["nodes"] == [{"name": "wire_test", "namespace": "/probe", "readers": [guids["command"]],
                                      "writers": [guids["poses"], guids["clock"]]}]


def test_samples_from_another_process_decode_in_rosbags_and_cyclonedds_to_what_was_sent():
    from cyclonedds.sub import DataReader
    from cyclonedds.topic import Topic

    domain, count = random_domain(), 5
    with Participant(domain_id=domain) as p:
        joints = p.reader(JOINTS, "sensor_msgs/msg/JointState")
        poses = p.reader(POSES, "geometry_msgs/msg/PoseArray")
        # cyclonedds' own deserializer on the same topic, as a second, independent decoder
        typed = DataReader(p.dds, Topic(p.dds, dds_topic_name(JOINTS), dds_type("sensor_msgs/msg/JointState").idl),
                           joints.qos.to_cyclone(joints.type.user_data))
        got_joints, got_poses, got_typed = [], [], []
        with spawn(CHILD, "publish", str(domain), str(count)) as publisher:
            while (len(got_joints) < count or len(got_poses) < count) and publisher.poll() is None:
                p.wait(0.5)
                for reader, got in ((joints, got_joints), (poses, got_poses)):
                    messages, refused = reader.take_messages()
                    assert refused == []
                    got += messages
                got_typed += [s for s in typed.take(N=64) if s.sample_info.valid_data]
            _, err = publisher.communicate(timeout=20)
        got_typed += [s for s in typed.take(N=64) if s.sample_info.valid_data]
    assert publisher.returncode == 0, err
    assert len(got_joints) == len(got_poses) == len(got_typed) == count
    for i in range(count):  # what was sent, as rosbags holds it (rclpy's classes, where it imports, are not)
        sent_joints = M.rosbags_message(joint_state(i), "sensor_msgs/msg/JointState")
        _same_content(sent_joints, got_joints[i], f"joints[{i}]")
        _same_content(M.rosbags_message(pose_array(i), "geometry_msgs/msg/PoseArray"), got_poses[i], f"poses[{i}]")
        _same_content(sent_joints, got_typed[i], f"typed[{i}]")
