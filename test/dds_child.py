"""Child processes for the DDS tests, and :func:`spawn` that runs them.

Each role is a separate process on the test's own random domain, over loopback only, and exits by
itself within its deadline:

    python dds_child.py publish DOMAIN COUNT   publish COUNT known JointStates and PoseArrays
    python dds_child.py observe DOMAIN SECONDS print, as JSON lines, what a ROS 2 graph sees
    python dds_child.py control DOMAIN ACTIONS  drive the simulator node: see :func:`control`
"""
import contextlib
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from tensegrity_sim.ros import messages as M
from tensegrity_sim.ros.dds import Participant, QosProfile, Reader, dds_type
from tensegrity_sim.ros.messages import TYPESTORE
from ros_env import free_domain
JOINTS = "/dds_test/joint_states"
POSES = "/dds_test/poses"


ROOT = Path(__file__).resolve().parents[1]


def random_domain() -> int:
    """A domain id of the test's own, so that concurrent runs do not hear each other (see ros_env)."""
    return free_domain()


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


def joint_state(i: int):
    """The i-th JointState the publisher sends; a test rebuilds it to compare."""
    k = np.arange(3.0)
    return M.joint_state(M.header(i * 10**9 + 1000 * i, f"frame_{i}"), [f"j{n}" for n in range(3)],
                         position=i + k / 10, velocity=-k)


def pose_array(i: int):
    """The i-th PoseArray: pose n at (i, n, -n) with a unit quaternion."""
    identity = M.new("geometry_msgs/msg/Quaternion", x=0.0, y=0.0, z=0.0, w=1.0)
    return M.new("geometry_msgs/msg/PoseArray", header=M.header(i * 10**9 + 1000 * i, f"frame_{i}"),
                 poses=[M.new("geometry_msgs/msg/Pose", position=M.point(float(i), float(n), -float(n)),
                              orientation=identity) for n in range(4)])


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
                info = TYPESTORE.deserialize_cdr(raw, "rmw_dds_common/msg/ParticipantEntitiesInfo")
                print(json.dumps({"kind": "node", "participant": bytes(info.gid.data).hex(), "nodes": [
                    {"name": n.node_name, "namespace": n.node_namespace,
                     "readers": [bytes(g.data).hex() for g in n.reader_gid_seq],
                     "writers": [bytes(g.data).hex() for g in n.writer_gid_seq]}
                    for n in info.node_entities_info_seq]}), flush=True)
            time.sleep(0.05)


NODE = "/tensegrity_sim"
NODE_OUTPUTS = {  # what the controller listens to, as the node documents it
    "clock": ("/clock", "rosgraph_msgs/msg/Clock"),
    "node_poses": (f"{NODE}/node_poses", "geometry_msgs/msg/PoseArray"),
    "cable_states": (f"{NODE}/cable_states", "sensor_msgs/msg/JointState"),
    "cable_impulses": (f"{NODE}/cable_impulses", "sensor_msgs/msg/JointState"),
    "contacts": (f"{NODE}/contacts", "diagnostic_msgs/msg/DiagnosticArray"),
    "command_result": (f"{NODE}/command_result", "std_msgs/msg/String"),
    "parameter_events": ("/parameter_events", "rcl_interfaces/msg/ParameterEvent"),
}
NODE_INPUTS = {
    "cable_rest_lengths": (f"{NODE}/cable_rest_lengths", "sensor_msgs/msg/JointState"),
    "external_wrench": (f"{NODE}/external_wrench", "geometry_msgs/msg/WrenchStamped"),
    "command": (f"{NODE}/command", "std_msgs/msg/String"),
}


def rest_lengths(names, position, velocity=()):
    return M.joint_state(M.header(0, ""), names, position=position, velocity=velocity)


def control(domain: int, actions: list) -> None:
    """Wait until the node publishes, then run ``actions`` in order, listening all along; print every
    sample received as a JSON line ``{"key", "cdr" (hex), "received" (monotonic s)}``, after checking
    that rosbags decodes it. Actions (JSON):

    ``{"sleep": s}``; ``{"rest": [names, position(, velocity)]}``; ``{"wrench": [node, force(, torque)]}``;
    ``{"command": text}``; ``{"cdr": [input key, hex]}`` sends raw bytes; ``{"wrong_type": input key}``
    publishes a std_msgs/String on that topic; ``{"mark": label}`` prints ``{"mark", "at"}``.
    """
    with Participant(domain_id=domain) as p:
        readers = {k: p.reader(topic, typename, QosProfile(depth=1000)) for k, (topic, typename) in NODE_OUTPUTS.items()}
        writers = {k: p.writer(topic, typename) for k, (topic, typename) in NODE_INPUTS.items()}
        strangers = {}

        def drain(seconds: float, until_any: bool = False) -> None:
            """Print what arrives for ``seconds`` s (``until_any``: or until a first sample)."""
            end = time.monotonic() + seconds
            while True:
                got = 0
                for key, reader in readers.items():
                    for data in reader.take():
                        TYPESTORE.deserialize_cdr(data, NODE_OUTPUTS[key][1])  # must decode, or the child fails
                        print(json.dumps({"key": key, "cdr": data.hex(), "received": time.monotonic()}))
                        got += 1
                if time.monotonic() >= end or (until_any and got):
                    return
                p.wait(min(0.01, max(end - time.monotonic(), 0.0)))

        deadline = time.monotonic() + 15
        while not readers["cable_states"].matched or not all(w.matched for w in writers.values()):
            if time.monotonic() > deadline:
                sys.exit("the node did not appear within 15 s")
            time.sleep(0.01)
        # the node publishes once warmed up (numba compiling a scene's kernels the first time takes seconds)
        drain(60.0, until_any=True)
        drain(0.2)
        for action in actions:
            (kind, arg), = action.items()
            if kind == "sleep":
                drain(arg)
            elif kind == "rest":
                writers["cable_rest_lengths"].write(rest_lengths(*arg))
            elif kind == "wrench":
                node, force, *torque = arg
                writers["external_wrench"].write(M.wrench_stamped(M.header(0, node), force, *torque))
            elif kind == "command":
                writers["command"].write(M.new("std_msgs/msg/String", data=arg))
            elif kind == "cdr":
                writers[arg[0]].write_cdr(bytes.fromhex(arg[1]))
            elif kind == "wrong_type":
                strangers[arg] = p.writer(NODE_INPUTS[arg][0], "std_msgs/msg/String")
                time.sleep(0.5)  # time to be discovered (and refused by type)
                strangers[arg].write(M.new("std_msgs/msg/String", data="not a JointState"))
            elif kind == "mark":
                print(json.dumps({"mark": arg, "at": time.monotonic()}))
            else:
                sys.exit(f"unknown action {kind!r}")
            sys.stdout.flush()
        drain(0.3)


if __name__ == "__main__":
    role, domain = sys.argv[1], int(sys.argv[2])
    if role == "publish":
        publish(domain, int(sys.argv[3]))
    elif role == "observe":
        observe(domain, float(sys.argv[3]))
    elif role == "control":
        control(domain, json.loads(sys.argv[3]))
    else:
        sys.exit(f"unknown role {role!r}")
