"""Two "hosts" on one machine: network namespaces joined by a veth pair, Fast DDS between them.

Fast DDS is configured the way a lab configures its machines: initial peers, UDP only.

Used by the ``multihost`` benchmark section (bench_multihost.py) and by
tests/system/test_multihost.py. Creating namespaces needs root (CAP_NET_ADMIN); every
namespace and link made here is deleted when the ``with`` block ends, and traffic stays
inside the two namespaces (their addresses exist nowhere else).

A process runs on a host through ``ip netns exec <namespace> env <variables> <command>``:
both ``ip netns exec`` and ``env`` replace themselves with the command, so the PID that
Popen returns is the node's own and stopping it by PID stops the node.
"""

from __future__ import annotations

import json
import os
import subprocess
import time
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from xml.sax.saxutils import escape

#: Addresses of the two hosts on their point-to-point link (a /30 inside the namespaces only).
LINK_ADDRESSES = ("10.231.0.1", "10.231.0.2")
LINK_PREFIX = 30

#: What every process on a host gets: the profile below, and a discovery range that leaves
#: the transports and peers to that profile (rmw_fastrtps changes nothing at SYSTEM_DEFAULT).
DISCOVERY_RANGE = "SYSTEM_DEFAULT"

#: Highest participant index a host's initial peers reach (one ROS 2 process = one
#: participant; Fast DDS's default of 4 is too few for a host running thermal, feedforward,
#: recorder and a probe).
MAX_PARTICIPANTS_PER_HOST = 16


#: UDP socket buffers [bytes]: a 64 x 64 grid is 32 KiB a message, so the kernel's default
#: receive buffer (208 KiB) holds a burst of six; capped by net.core.rmem_max/wmem_max.
SOCKET_BUFFER_BYTES = 4 * 1024 * 1024

#: Longest wait for a link end to come operationally up after ``ip link set up`` [s].
LINK_UP_TIMEOUT_S = 30.0


class NetnsError(RuntimeError):
    """The network namespaces or their link cannot be created (e.g. not root)."""


@dataclass(frozen=True)
class Host:
    """One network namespace standing for one machine of the lab.

    Attributes:
        namespace: name of the Linux network namespace.
        device: name of its end of the veth link.
        address: its IPv4 address on the link.

    """

    namespace: str
    device: str
    address: str

    def command(self, argv: Sequence[str], env: Mapping[str, str]) -> list[str]:
        """Return ``argv`` as run on this host with the extra environment ``env``."""
        assignments = [f"{key}={value}" for key, value in env.items()]
        return ["ip", "netns", "exec", self.namespace, "env", *assignments, *argv]

    def link_bytes(self) -> tuple[int, int]:
        """Return (received, sent) bytes counted on this host's end of the link.

        Raises:
            NetnsError: the link cannot be read.

        """
        out = _ip("-n", self.namespace, "-s", "-j", "link", "show", "dev", self.device)
        try:
            stats = json.loads(out)[0]["stats64"]
            return int(stats["rx"]["bytes"]), int(stats["tx"]["bytes"])
        except (ValueError, LookupError, TypeError) as err:
            raise NetnsError(f"cannot read the counters of {self.device}: {err}") from None

    def link_running(self) -> bool:
        """Return whether this host's end of the link is operationally up (IFF_RUNNING).

        Raises:
            NetnsError: the link cannot be read.

        """
        out = _ip("-n", self.namespace, "-j", "link", "show", "dev", self.device)
        try:
            link = json.loads(out)[0]
            return bool(link["operstate"] == "UP" and "LOWER_UP" in link["flags"])
        except (ValueError, LookupError, TypeError) as err:
            raise NetnsError(f"cannot read the state of {self.device}: {err}") from None


def _ip(*args: str) -> str:
    try:
        done = subprocess.run(["ip", *args], capture_output=True, text=True, check=False,
                              timeout=30)
    except (OSError, subprocess.TimeoutExpired) as err:
        raise NetnsError(f"'ip {' '.join(args)}' failed: {err}") from None
    if done.returncode != 0:
        raise NetnsError(f"'ip {' '.join(args)}' failed ({done.stderr.strip()}); network "
                         "namespaces need root (CAP_NET_ADMIN) and iproute2")
    return done.stdout


@contextmanager
def two_hosts(tag: str | None = None) -> Iterator[tuple[Host, Host]]:
    """Create two namespaces joined by a veth pair, yield them, delete them afterwards.

    ``tag`` makes the names unique on the machine (default: this process's PID), so that
    several runs can go at once; the link addresses are the same in every pair, which is
    fine: each pair is its own network.

    Raises:
        NetnsError: a namespace or the link cannot be created (nothing is left behind).

    """
    tag = tag or str(os.getpid())
    hosts = tuple(Host(f"esdm-{tag}-{side}", f"esdm{tag[:10]}{side}", address)  # IFNAMSIZ 16
                  for side, address in zip("ab", LINK_ADDRESSES, strict=True))
    created: list[str] = []
    try:
        for host in hosts:
            _ip("netns", "add", host.namespace)
            created.append(host.namespace)
        first, second = hosts
        _ip("link", "add", first.device, "netns", first.namespace, "type", "veth",
            "peer", "name", second.device, "netns", second.namespace)
        for host in hosts:
            _ip("-n", host.namespace, "addr", "add", f"{host.address}/{LINK_PREFIX}",
                "dev", host.device)
            _ip("-n", host.namespace, "link", "set", host.device, "up")
            _ip("-n", host.namespace, "link", "set", "lo", "up")
        _wait_running(hosts)
        yield first, second
    finally:
        for namespace in reversed(created):  # the veth ends go with their namespaces
            subprocess.run(["ip", "netns", "del", namespace], capture_output=True, check=False,
                           timeout=30)


def _wait_running(hosts: Sequence[Host], timeout_s: float = LINK_UP_TIMEOUT_S) -> None:
    """Return once every host's link end is operationally up.

    The kernel marks a veth end running (operstate UP) a little after ``ip link set up``,
    later on a loaded machine. A Fast DDS participant lists the running interfaces once, when
    it is created: one created before that announces only 127.0.0.1, and the other host can
    then match its endpoints (it sends to the peer's announced addresses) but never reach it.

    Raises:
        NetnsError: a link end is still not up after ``timeout_s`` seconds.

    """
    deadline = time.monotonic() + timeout_s
    waiting = list(hosts)
    while waiting:
        waiting = [host for host in waiting if not host.link_running()]
        if not waiting:
            return
        if time.monotonic() > deadline:
            names = ", ".join(f"{h.device} in {h.namespace}" for h in waiting)
            raise NetnsError(f"link not operationally up after {timeout_s:g} s: {names}")
        time.sleep(0.02)


def fastdds_profile(peers: Sequence[str], participant_id: int | None = None,
                    address: str | None = None) -> str:
    """Return a Fast DDS XML profile for a graph spread over the hosts ``peers`` (IPv4).

    The default participant profile: UDPv4 only (no shared memory, which would bypass the
    network between processes of one machine) with socket buffers for large grids, and
    every host of the graph as an initial peer, so discovery needs no multicast.
    ``participant_id`` pins the participant index (and so its ports); ``None`` lets Fast DDS
    pick the lowest free one, and then one file serves every process of every host.
    ``address`` (the process's own host, IPv4) is announced as its only unicast address for
    discovery and data; ``None`` announces every interface that is up when the participant
    is created (a participant created before its host's link is up then announces only
    127.0.0.1, and the other host matches it but never reaches it).

    Raises:
        ValueError: ``participant_id`` is outside 0 .. MAX_PARTICIPANTS_PER_HOST - 1 (the
            initial peers would not reach it).

    """
    if participant_id is not None and not 0 <= participant_id < MAX_PARTICIPANTS_PER_HOST:
        raise ValueError(f"participant_id must be in 0..{MAX_PARTICIPANTS_PER_HOST - 1}, "
                         f"got {participant_id}")
    locators = "\n".join(
        f"          <locator><udpv4><address>{escape(peer)}</address></udpv4></locator>"
        for peer in peers)
    pinned = ("" if participant_id is None
              else f"\n      <participantID>{participant_id}</participantID>")
    own = ("" if address is None
           else f"<locator><udpv4><address>{escape(address)}</address></udpv4></locator>")
    default_unicast = ("" if address is None else
                       f"\n      <defaultUnicastLocatorList>{own}</defaultUnicastLocatorList>")
    meta_unicast = ("" if address is None else
                    f"\n        <metatrafficUnicastLocatorList>{own}"
                    "</metatrafficUnicastLocatorList>")
    return f"""<?xml version="1.0" encoding="UTF-8" ?>
<profiles xmlns="http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles">
  <transport_descriptors>
    <transport_descriptor>
      <transport_id>es_dm_udp</transport_id>
      <type>UDPv4</type>
      <maxInitialPeersRange>{MAX_PARTICIPANTS_PER_HOST}</maxInitialPeersRange>
      <sendBufferSize>{SOCKET_BUFFER_BYTES}</sendBufferSize>
      <receiveBufferSize>{SOCKET_BUFFER_BYTES}</receiveBufferSize>
    </transport_descriptor>
  </transport_descriptors>
  <participant profile_name="es_dm_hosts" is_default_profile="true">
    <rtps>{pinned}
      <userTransports>
        <transport_id>es_dm_udp</transport_id>
      </userTransports>
      <useBuiltinTransports>false</useBuiltinTransports>{default_unicast}
      <builtin>{meta_unicast}
        <initialPeersList>
{locators}
        </initialPeersList>
      </builtin>
    </rtps>
  </participant>
</profiles>
"""


def host_environment(directory: Path, participant_id: int, address: str,
                     peers: Sequence[str] = LINK_ADDRESSES) -> dict[str, str]:
    """Write the profile of one process into ``directory``; return the variables it needs.

    ``address`` is the IPv4 address of the process's host, the one it announces.
    Every process of the graph gets its own ``participant_id`` (unique over all hosts):
    with automatic indices, the first process of one namespace and the first of the other
    (both index 0, the same ports) found each other in only about two runs of three here,
    while with distinct indices every run did.

    Raises:
        ValueError: ``participant_id`` out of range (:func:`fastdds_profile`).

    """
    directory.mkdir(parents=True, exist_ok=True)
    path = directory / f"fastdds_participant_{participant_id}.xml"
    path.write_text(fastdds_profile(peers, participant_id, address), encoding="utf-8")
    return {"FASTRTPS_DEFAULT_PROFILES_FILE": str(path),
            "ROS_AUTOMATIC_DISCOVERY_RANGE": DISCOVERY_RANGE,
            "RMW_IMPLEMENTATION": "rmw_fastrtps_cpp"}
