"""The Cyclone DDS configuration (the XML that ``CYCLONEDDS_URI`` would hold), generated per run.

Two settings matter to users: the domain id (ROS_DOMAIN_ID) and the network interface. On a
loopback interface multicast usually does not work (Linux's ``lo`` has no MULTICAST flag), so
discovery there is unicast to 127.0.0.1, with a participant index per process so that several
processes on one host find each other, which is how ROS 2 runs "localhost only". On any other
interface Cyclone's default multicast discovery is kept, so a ROS 2 machine on the same network and
domain sees the topics.
"""
from __future__ import annotations

import ipaddress
import socket
from pathlib import Path

__all__ = ["AUTO_INTERFACE", "DEFAULT_INTERFACE", "MAX_DOMAIN_ID", "check_domain_id", "cyclone_config",
           "ros_peer_settings"]

AUTO_INTERFACE = "auto"        # let Cyclone pick (its first multicast-capable interface)
DEFAULT_INTERFACE = "lo"
MAX_DOMAIN_ID = 232            # the RTPS port mapping overflows 16 bits above this
MAX_PARTICIPANTS_PER_HOST = 32  # unicast discovery probes this many participant indices on 127.0.0.1
_IFF_LOOPBACK = 0x8


def check_domain_id(domain_id) -> int:
    """The domain id as an int in [0, MAX_DOMAIN_ID]; ValueError otherwise."""
    if isinstance(domain_id, bool) or not isinstance(domain_id, int) or not 0 <= domain_id <= MAX_DOMAIN_ID:
        raise ValueError(f"domain_id must be a whole number in [0, {MAX_DOMAIN_ID}], got {domain_id!r}")
    return domain_id


def _is_loopback(interface: str) -> bool:
    try:
        return ipaddress.ip_address(interface).is_loopback
    except ValueError:
        pass
    flags = Path("/sys/class/net") / interface / "flags"
    if flags.exists():  # Linux: ask the kernel rather than guess from the name
        return bool(int(flags.read_text(), 16) & _IFF_LOOPBACK)
    return interface.startswith("lo")


def ros_peer_settings(interface: str, domain_id: int) -> str | None:
    """What a ROS 2 Jazzy process on this host sets to find a participant on a loopback ``interface``
    (None for any other interface, where Jazzy's default multicast discovery works). Its default
    discovery is multicast only, which the loopback does not carry, and a Fast DDS participant (Jazzy's
    default middleware) does not answer a Cyclone DDS participant that reached it by unicast from
    127.0.0.1 unless 127.0.0.1 is one of its static peers (checked with rclpy 7.1.6, rmw_fastrtps_cpp)."""
    if interface == AUTO_INTERFACE or not _is_loopback(interface):
        return None
    return f"ROS_DOMAIN_ID={domain_id} ROS_STATIC_PEERS=127.0.0.1"


def cyclone_config(interface: str = DEFAULT_INTERFACE) -> str:
    """The Cyclone DDS XML configuration for ``interface``: a name (``lo``, ``eth0``), an address
    of this host, or ``"auto"``. Raises ValueError naming an interface this host does not have."""
    if not isinstance(interface, str) or not interface:
        raise ValueError(f"interface must be a network interface name or address, got {interface!r}")
    if interface == AUTO_INTERFACE:
        return "<CycloneDDS><Domain Id=\"any\"/></CycloneDDS>"
    try:
        ipaddress.ip_address(interface)
        selector = f'address="{interface}"'
    except ValueError:
        names = [name for _, name in socket.if_nameindex()]
        if interface not in names:
            raise ValueError(f"interface: no network interface named {interface!r} here "
                             f"(have: {', '.join(names)}; or give an address, or 'auto')") from None
        selector = f'name="{interface}"'
    discovery = ""
    general = ""
    if _is_loopback(interface):
        general = "<AllowMulticast>false</AllowMulticast>"
        discovery = ("<Discovery><ParticipantIndex>auto</ParticipantIndex>"
                     f"<MaxAutoParticipantIndex>{MAX_PARTICIPANTS_PER_HOST - 1}</MaxAutoParticipantIndex>"
                     "<Peers><Peer address=\"127.0.0.1\"/></Peers></Discovery>")
    return ("<CycloneDDS><Domain Id=\"any\"><General>"
            f"<Interfaces><NetworkInterface {selector}/></Interfaces>{general}</General>"
            f"{discovery}</Domain></CycloneDDS>")
