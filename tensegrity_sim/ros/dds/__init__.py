"""ROS 2 topics over DDS without a ROS install (Eclipse Cyclone DDS, the ``dds`` extra).

A ROS 2 Jazzy machine on the same domain and network sees these topics as its own: ROS topic and
type naming, keyless final structs generated from the Jazzy message definitions, XCDR1, ROS QoS,
the RIHS01 type hash in USER_DATA, and the node announced on ``ros_discovery_info``.

- ``types``: DDS types and names generated from the rosbags Jazzy typestore of ``messages``;
- ``config``: the Cyclone configuration for a domain id and a network interface;
- ``participant``: a participant with ROS-convention readers and writers of CDR bytes.
"""
from .config import (AUTO_INTERFACE, DEFAULT_INTERFACE, MAX_DOMAIN_ID, check_domain_id, cyclone_config,
                     ros_peer_settings)
from .participant import DEFAULT_QOS, Participant, QosProfile, Reader, Writer
from .types import DdsType, dds_topic_name, dds_type

__all__ = [
    "AUTO_INTERFACE", "DEFAULT_INTERFACE", "DEFAULT_QOS", "MAX_DOMAIN_ID", "DdsType", "Participant",
    "QosProfile", "Reader", "Writer", "check_domain_id", "cyclone_config", "dds_topic_name", "dds_type",
    "ros_peer_settings",
]
