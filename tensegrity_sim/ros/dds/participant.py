"""A DDS participant that speaks ROS 2 (Jazzy) on the wire, without a ROS install.

Writers send CDR bytes whose layout is the generated type's (see ``types``), serialized by
:mod:`~tensegrity_sim.ros.messages` as the MCAP log serializes them, so what goes on the wire is byte for
byte what goes in the log; messages are that module's (rclpy's classes where rclpy imports, else
rosbags'). Readers hand back the raw CDR of every sample; ``take_messages`` decodes it and refuses,
with a reason, whatever does not decode, since a network peer can send anything.

Endpoint QoS follows rmw_cyclonedds: history, reliability and durability from the ROS profile,
liveliness automatic with an infinite lease, no autodispose, XCDR1 data representation, and
``typehash=RIHS01_...;`` in USER_DATA. With ``node_name`` the participant also announces the node on
``ros_discovery_info`` (rmw_dds_common/msg/ParticipantEntitiesInfo) so that ``ros2 node list`` and
``ros2 topic info -v`` on a ROS 2 machine name it.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cyclonedds.core import DDSException, InstanceState, ReadCondition, SampleState, ViewState, WaitSet
from cyclonedds.domain import Domain, DomainParticipant
from cyclonedds.pub import DataWriter
from cyclonedds.qos import Policy, Qos
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.util import duration
# The binding's own write/take of serialized samples: DataWriter.write and DataReader.take would
# force every message through cyclonedds' Python (de)serializer objects; these take and give bytes.
from cyclonedds._clayer import ddspy_take, ddspy_write
from .. import messages as M
from .config import DEFAULT_INTERFACE, check_domain_id, cyclone_config
from .types import DdsType, dds_topic_name, dds_type

__all__ = ["DEFAULT_QOS", "Participant", "QosProfile", "Reader", "Writer"]

_ANY_SAMPLE = SampleState.Any | ViewState.Any | InstanceState.Any
_DISCOVERY_TOPIC = "ros_discovery_info"
_DISCOVERY_TYPE = "rmw_dds_common/msg/ParticipantEntitiesInfo"
_MAX_BLOCKING = duration(milliseconds=100)  # a writer never stalls the simulation longer than this


@dataclass(frozen=True)
class QosProfile:
    """The part of a ROS 2 QoS profile that DDS matching sees. depth: KEEP_LAST history depth (>= 1)."""

    reliable: bool = True
    depth: int = 10
    transient_local: bool = False

    def __post_init__(self):
        if isinstance(self.depth, bool) or not isinstance(self.depth, int) or self.depth < 1:
            raise ValueError(f"depth must be a whole number >= 1, got {self.depth!r}")

    def to_cyclone(self, user_data: bytes) -> Qos:
        """The Cyclone QoS of a reader or writer with this profile, as rmw_cyclonedds builds it."""
        return Qos(
            Policy.Reliability.Reliable(max_blocking_time=_MAX_BLOCKING) if self.reliable
            else Policy.Reliability.BestEffort,
            Policy.Durability.TransientLocal if self.transient_local else Policy.Durability.Volatile,
            Policy.History.KeepLast(self.depth),
            Policy.Liveliness.Automatic(lease_duration=duration(infinite=True)),
            Policy.WriterDataLifecycle(autodispose=False),
            Policy.DataRepresentation(use_cdrv0_representation=True),  # XCDR1 only: plain CDR
            Policy.Userdata(user_data),
        )


DEFAULT_QOS = QosProfile()  # rmw_qos_profile_default: reliable, volatile, keep last 10


class _Endpoint:
    """What readers and writers share. ``topic``: the ROS name; ``dds_topic``: the DDS one."""

    def __init__(self, participant: "Participant", topic: str, dds_topic: str, dds: DdsType, qos: QosProfile,
                 entity):
        self.topic, self.type, self.qos = topic, dds, qos
        self._entity = entity(participant.dds, Topic(participant.dds, dds_topic, dds.idl),
                              qos.to_cyclone(dds.user_data))

    @property
    def guid(self) -> bytes:
        """The 16-byte GUID, what ROS 2 calls the endpoint's gid."""
        return self._entity.guid.bytes


class Writer(_Endpoint):
    """Publishes one topic."""

    def __init__(self, participant: "Participant", topic: str, dds_topic: str, dds: DdsType, qos: QosProfile):
        super().__init__(participant, topic, dds_topic, dds, qos, DataWriter)

    @property
    def matched(self) -> int:
        """How many readers are matched now."""
        return len(self._entity.get_matched_subscriptions())

    def write(self, message) -> None:
        """Serialize a message (of :mod:`~tensegrity_sim.ros.messages`) and send it."""
        self.write_cdr(M.serialize(message, self.type.msgtype))

    def write_cdr(self, data: bytes) -> None:
        """Send one serialized sample: the 4-byte encapsulation header (CDR_LE or CDR_BE) then the body."""
        # RTPS carries serialized payloads in multiples of 4 bytes; the binding's own write pads alike.
        ret = ddspy_write(self._entity._ref, data.ljust((len(data) + 3) & ~3, b"\0"))
        if ret < 0:
            raise DDSException(ret, f"writing {self.topic}")


class Reader(_Endpoint):
    """Subscribes to one topic; ``condition`` triggers while it holds samples."""

    def __init__(self, participant: "Participant", topic: str, dds_topic: str, dds: DdsType, qos: QosProfile):
        super().__init__(participant, topic, dds_topic, dds, qos, DataReader)
        self.condition = ReadCondition(self._entity, _ANY_SAMPLE)

    @property
    def matched(self) -> int:
        """How many writers are matched now."""
        return len(self._entity.get_matched_publications())

    def take(self, max_samples: int = 256) -> list[bytes]:
        """The raw CDR (header included) of up to ``max_samples`` received samples, oldest first."""
        got = ddspy_take(self._entity._ref, _ANY_SAMPLE, max_samples)
        if isinstance(got, int):
            raise DDSException(got, f"taking from {self.topic}")
        return [data for data, info in got if info.valid_data]

    def take_messages(self, max_samples: int = 256) -> tuple[list, list[str]]:
        """Decode what :meth:`take` returns: (messages, one reason per sample that does not decode)."""
        messages, refused = [], []
        for data in self.take(max_samples):
            try:
                messages.append(M.deserialize(data, self.type.msgtype))
            # Bytes from the network are untrusted: whatever the decoder raises on them refuses
            # that sample and nothing else.
            except Exception as exc:  # noqa: BLE001
                refused.append(f"undecodable {self.type.msgtype} ({len(data)} bytes): {exc}")
        return messages, refused


class Participant:
    """One DDS participant on ``domain_id`` over ``interface`` (see :func:`cyclone_config`).

    ``node_name`` (optional, with ``namespace``): announce a ROS node owning every endpoint made here.
    Use as a context manager or call :meth:`close`; closing deletes every entity, which tells the
    peers at once that they are gone.
    """

    def __init__(self, *, domain_id: int = 0, interface: str = DEFAULT_INTERFACE, node_name: str | None = None,
                 namespace: str = "/"):
        self.domain_id = check_domain_id(domain_id)
        self._closed = True  # until the participant exists
        _domains.acquire(self.domain_id, cyclone_config(interface), interface)
        try:
            # Jazzy participants carry their security enclave; "/" is the default one.
            self.dds = DomainParticipant(self.domain_id, qos=Qos(Policy.Userdata(b"enclave=/;")))
        except DDSException as exc:
            _domains.release(self.domain_id)
            raise ValueError(f"cannot start DDS on domain {domain_id} over interface {interface!r}: {exc}") from None
        self._closed = False
        self._endpoints: list[Writer | Reader] = []
        self._waitset = WaitSet(self.dds)
        self._node = None
        if node_name is not None:
            self._node = (namespace, node_name)
            # rmw_dds_common's own topic keeps its bare name (no "rt/"), and is not the node's.
            self._discovery = Writer(self, _DISCOVERY_TOPIC, _DISCOVERY_TOPIC, dds_type(_DISCOVERY_TYPE),
                                     QosProfile(depth=1, transient_local=True))

    @property
    def guid(self) -> bytes:
        return self.dds.guid.bytes

    def writer(self, topic: str, msgtype: str, qos: QosProfile = DEFAULT_QOS) -> Writer:
        """A writer of ``msgtype`` (``pkg/msg/Type``) on the fully qualified ROS topic ``topic``."""
        return self._add(Writer(self, topic, dds_topic_name(topic), dds_type(msgtype), qos))

    def reader(self, topic: str, msgtype: str, qos: QosProfile = DEFAULT_QOS) -> Reader:
        """A reader of ``msgtype`` on ``topic``; :meth:`wait` wakes when it has data."""
        reader = self._add(Reader(self, topic, dds_topic_name(topic), dds_type(msgtype), qos))
        self._waitset.attach(reader.condition)
        return reader

    def wait(self, timeout: float) -> bool:
        """Block until a reader made here has data or ``timeout`` s pass; True if data is there."""
        return self._waitset.wait(duration(seconds=max(timeout, 0.0))) > 0

    def close(self) -> None:
        """Delete the participant and everything in it (which says so on the network). Idempotent."""
        if self._closed:
            return
        self._closed = True
        # The binding deletes an entity, and everything under it, when its handle goes; dropping the
        # Python handles of the children afterwards is then a no-op.
        self.dds.__del__()
        _domains.release(self.domain_id)

    def __enter__(self) -> "Participant":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _add(self, endpoint):
        self._endpoints.append(endpoint)
        if self._node is not None:
            self._announce()
        return endpoint

    def _announce(self) -> None:
        """Publish which readers and writers belong to the node (rmw_dds_common's graph protocol)."""
        namespace, name = self._node
        node = M.new("rmw_dds_common/msg/NodeEntitiesInfo", node_namespace=namespace, node_name=name,
                     reader_gid_seq=[_gid(e.guid) for e in self._endpoints if isinstance(e, Reader)],
                     writer_gid_seq=[_gid(e.guid) for e in self._endpoints if isinstance(e, Writer)])
        self._discovery.write(M.new(_DISCOVERY_TYPE, gid=_gid(self.guid), node_entities_info_seq=[node]))


class _Domains:
    """The Cyclone domains of this process, one per domain id, shared by its participants and deleted
    with the last of them (as rmw_cyclonedds does): Cyclone configures a domain once per process."""

    def __init__(self):
        self._open: dict[int, tuple[Domain, str, str, int]] = {}  # id -> (domain, config, interface, users)

    def acquire(self, domain_id: int, config: str, interface: str) -> None:
        if domain_id in self._open:
            domain, held, held_interface, users = self._open[domain_id]
            if held != config:
                raise ValueError(f"domain {domain_id} is already in use in this process over interface "
                                 f"{held_interface!r}, not {interface!r}")
            self._open[domain_id] = (domain, held, held_interface, users + 1)
            return
        try:
            self._open[domain_id] = (Domain(domain_id, config), config, interface, 1)
        except DDSException as exc:
            raise ValueError(f"cannot start DDS on domain {domain_id} over interface {interface!r}: {exc}") from None

    def release(self, domain_id: int) -> None:
        domain, config, interface, users = self._open[domain_id]
        if users > 1:
            self._open[domain_id] = (domain, config, interface, users - 1)
        else:
            del self._open[domain_id]
            domain.__del__()


_domains = _Domains()


def _gid(guid: bytes):
    """A GUID as rmw_dds_common/msg/Gid (``char[16] data``)."""
    return M.new("rmw_dds_common/msg/Gid", data=np.frombuffer(guid, dtype=np.uint8))
