"""The ROS 2 environment of a test process: its own domain id, discovery on this host only."""
import errno
import os
import random
import socket

DOMAINS = range(1, 101)  # ROS 2's portable range is 0..101 (higher ids reach Linux's ephemeral ports); 0 is everyone's


def _port_taken(port: int) -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            s.bind(("127.0.0.1", port))
        except OSError as exc:
            if exc.errno == errno.EADDRINUSE:
                return True
            raise
    return False


def free_domain() -> int:
    """A domain id that no DDS participant on this host uses now: starting at a random id, the first whose
    RTPS discovery ports (7400 + 250 d: multicast; 7410 + 250 d: the unicast port of participant 0, which
    Fast DDS and Cyclone DDS both bind) are both free. A random start keeps concurrent runs apart even
    when two of them probe at once."""
    start = random.SystemRandom().randrange(len(DOMAINS))
    for k in range(len(DOMAINS)):
        domain = DOMAINS[(start + k) % len(DOMAINS)]
        if not any(_port_taken(7400 + 250 * domain + offset) for offset in (0, 10)):
            return domain
    raise RuntimeError(f"every ROS domain id in {DOMAINS} is in use on this host")


def isolate() -> int:
    """Give this process (and the processes it starts) a free domain and discovery on this host only,
    whatever the machine's environment says; returns the domain id."""
    domain = free_domain()
    os.environ["ROS_DOMAIN_ID"] = str(domain)
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    for name in ("ROS_STATIC_PEERS", "ROS_LOCALHOST_ONLY", "ROS_DISCOVERY_SERVER", "FASTRTPS_DEFAULT_PROFILES_FILE",
                 "FASTDDS_DEFAULT_PROFILES_FILE", "CYCLONEDDS_URI"):
        os.environ.pop(name, None)
    return domain
