"""Child processes for the DDS tests, and :func:`spawn` that runs them.

Each role is a separate process on the test's own random domain, over loopback only, and exits by
itself within its deadline:

    python dds_child.py publish DOMAIN COUNT   publish COUNT known JointStates and PoseArrays
    python dds_child.py observe DOMAIN SECONDS print, as JSON lines, what a ROS 2 graph sees
"""
import contextlib
import json
import os
import random
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from tensegrity_sim.dds import JAZZY, Participant, QosProfile, Reader, dds_type

T = JAZZY.types
JOINTS = "/dds_test/joint_states"
POSES = "/dds_test/poses"


ROOT = Path(__file__).resolve().parents[1]


def random_domain() -> int:
    """A domain id of the test's own, so that concurrent runs do not hear each other."""
    return random.SystemRandom().randint(1, 200)


@contextlib.contextmanager
def spawn(*args: str, timeout: float = 30.0):
    """Run ``python *args`` (this worktree's package first on the path); yield the Popen with text
    pipes. On the way out the process is given ``timeout`` s to finish, then killed: never leaked."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    proc = subprocess.Popen([sys.executable, *args], stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=env, cwd=ROOT)
    try:
        yield proc
        if proc.poll() is None:
            proc.communicate(timeout=timeout)  # drains the pipes, so the child cannot block on them
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=10)
        proc.stdout.close()
        proc.stderr.close()


def header(i: int):
    return T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=i, nanosec=1000 * i),
                                    frame_id=f"frame_{i}")


def joint_state(i: int):
    """The i-th JointState the publisher sends; a test rebuilds it to compare."""
    k = np.arange(3.0)
    return T["sensor_msgs/msg/JointState"](header=header(i), name=[f"j{n}" for n in range(3)],
                                           position=i + k / 10, velocity=-k, effort=np.array([]))


def pose_array(i: int):
    """The i-th PoseArray: pose n at (i, n, -n) with a unit quaternion."""
    pose, point, quat = T["geometry_msgs/msg/Pose"], T["geometry_msgs/msg/Point"], T["geometry_msgs/msg/Quaternion"]
    return T["geometry_msgs/msg/PoseArray"](
        header=header(i),
        poses=[pose(position=point(x=float(i), y=float(n), z=-float(n)), orientation=quat(x=0.0, y=0.0, z=0.0, w=1.0))
               for n in range(4)])


def publish(domain: int, count: int) -> None:
    with Participant(domain_id=domain, node_name="dds_child") as p:
        joints = p.writer(JOINTS, "sensor_msgs/msg/JointState")
        poses = p.writer(POSES, "geometry_msgs/msg/PoseArray")
        deadline = time.monotonic() + 10
        while (joints.matched < 1 or poses.matched < 1) and time.monotonic() < deadline:
            time.sleep(0.01)
        for i in range(count):
            joints.write(joint_state(i))
            poses.write(pose_array(i))
        time.sleep(1.0)  # reliable delivery of the last samples before the participant goes


def observe(domain: int, seconds: float) -> None:
    from cyclonedds.builtin import BuiltinDataReader, BuiltinTopicDcpsPublication, BuiltinTopicDcpsSubscription
    from cyclonedds.qos import Policy

    with Participant(domain_id=domain) as p:
        readers = {"publication": BuiltinDataReader(p.dds, BuiltinTopicDcpsPublication),
                   "subscription": BuiltinDataReader(p.dds, BuiltinTopicDcpsSubscription)}
        # rmw's graph topic: no "rt/" prefix, transient local like rmw's own reader of it
        discovery = Reader(p, "ros_discovery_info", "ros_discovery_info",
                           dds_type("rmw_dds_common/msg/ParticipantEntitiesInfo"), QosProfile(transient_local=True))
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            for kind, reader in readers.items():
                for e in reader.take(N=64):
                    if not e.sample_info.valid_data or e.participant_key.bytes == p.guid:
                        continue
                    qos = e.qos
                    print(json.dumps({
                        "kind": kind, "guid": e.key.bytes.hex(), "topic": e.topic_name, "type": e.type_name,
                        "user_data": qos[Policy.Userdata].data.decode() if Policy.Userdata in qos else "",
                        "reliable": isinstance(qos[Policy.Reliability], Policy.Reliability.Reliable),
                        "transient_local": qos[Policy.Durability] == Policy.Durability.TransientLocal,
                        "depth": qos[Policy.History].depth,
                        "xcdr1_only": qos[Policy.DataRepresentation] == Policy.DataRepresentation(
                            use_cdrv0_representation=True),
                    }), flush=True)
            for raw in discovery.take():
                info = JAZZY.deserialize_cdr(raw, "rmw_dds_common/msg/ParticipantEntitiesInfo")
                print(json.dumps({"kind": "node", "participant": bytes(info.gid.data).hex(), "nodes": [
                    {"name": n.node_name, "namespace": n.node_namespace,
                     "readers": [bytes(g.data).hex() for g in n.reader_gid_seq],
                     "writers": [bytes(g.data).hex() for g in n.writer_gid_seq]}
                    for n in info.node_entities_info_seq]}), flush=True)
            time.sleep(0.05)


if __name__ == "__main__":
    role, domain = sys.argv[1], int(sys.argv[2])
    if role == "publish":
        publish(domain, int(sys.argv[3]))
    elif role == "observe":
        observe(domain, float(sys.argv[3]))
    else:
        sys.exit(f"unknown role {role!r}")
