"""Fast DDS configuration of every es_dm process: a segment that holds grids, quick repairs.

Fast DDS sends a sample to a process on the same host through a shared-memory segment of
the writer (512 KiB by default). A 128 x 128 grid is 128 KiB, so at most three are in
flight: when a reader falls a few samples behind (a scheduler stall of a few ms), the writer
finds the segment full, the samples that did not fit are repaired later by the reliable
protocol, and a stall of 20 ms became one of 60-85 ms (measured: the feedforward node and a
plain relay at 128 x 128 / 1 kHz, the node stopped for 20 ms; with a 16 MiB segment the
stall stayed 23-24 ms). :func:`configure_middleware` makes a process use a segment of
:data:`SHM_SEGMENT_BYTES` through a Fast DDS XML profile, unless its environment names one
already (``FASTRTPS_DEFAULT_PROFILES_FILE``: a lab's own profile wins) or it runs another
RMW. It must run before the process's first ROS context is initialised.

A sample that did not fit into a reader's shared-memory port (a reader starved of CPU for a
few hundred samples) is sent again only when the writer's next heartbeat asks the reader what
it lacks: Fast DDS's default period is 3 s, in which a plant running free at 1,100 steps/s
publishes 3,300 samples per topic, and a writer keeps the contract's newest 1,000: the
repair found them gone, and the recorder's bag had a hole (issue 35: 30 to 1,530 messages of
a characterisation run lost, the recorder's "lost before reception"). The profile's writers
send heartbeats every :data:`HEARTBEAT_PERIOD_S`, so a repair comes while the writer still
holds the sample, and a writer waiting for its readers' acknowledgements (the plant's flow
control, the end of a run) hears them within that period (measured on the demo's two
test-stand runs side by side on 2 cores: with the default, one run's recorder lost 1,810 of
its 21,601 command and displacement messages; with 50 ms none, and the pair took 25 s of wall
time instead of 84 s, most of which had been end-of-run waits for acknowledgements).

The segment is memory of /dev/shm, used only as far as samples fill it. The profile adds the
transport to the ones ROS sets up itself (discovery, ``ROS_AUTOMATIC_DISCOVERY_RANGE`` and
the other transports stay as they are).
"""

from __future__ import annotations

import os
import sys
import tempfile
from pathlib import Path
from typing import Final

#: Size of the shared-memory segment of every es_dm participant [bytes]: 16 MiB, about a
#: hundred 128 x 128 samples (100 ms at 1 kHz) in flight.
SHM_SEGMENT_BYTES: Final = 16 * 1024 * 1024
#: Heartbeat period of every es_dm writer [s]: how soon a reader's missing samples are sent
#: again and its acknowledgements come back (a heartbeat is sent only while some sample is
#: unacknowledged, so an idle writer costs nothing).
HEARTBEAT_PERIOD_S: Final = 0.05
#: The environment variable through which Fast DDS 2.x loads its default XML profile.
PROFILES_VARIABLE: Final = "FASTRTPS_DEFAULT_PROFILES_FILE"
#: RMW implementations this profile is for (unset: ROS 2's default, Fast DDS).
FASTDDS_RMWS: Final = ("rmw_fastrtps_cpp", "rmw_fastrtps_dynamic_cpp")


def profile_xml(segment_bytes: int = SHM_SEGMENT_BYTES) -> str:
    """Return the Fast DDS XML profile: a shared-memory transport of ``segment_bytes``.

    Its writers send heartbeats every :data:`HEARTBEAT_PERIOD_S`.

    Raises:
        ValueError: ``segment_bytes`` is not positive.

    """
    if segment_bytes <= 0:
        raise ValueError(f"shared-memory segment must be positive, got {segment_bytes} bytes")
    heartbeat_ns = round(HEARTBEAT_PERIOD_S * 1e9)
    return f"""<?xml version="1.0" encoding="UTF-8" ?>
<profiles xmlns="http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles">
  <transport_descriptors>
    <transport_descriptor>
      <transport_id>es_dm_shm</transport_id>
      <type>SHM</type>
      <segment_size>{segment_bytes}</segment_size>
    </transport_descriptor>
  </transport_descriptors>
  <participant profile_name="es_dm" is_default_profile="true">
    <rtps>
      <userTransports>
        <transport_id>es_dm_shm</transport_id>
      </userTransports>
      <useBuiltinTransports>true</useBuiltinTransports>
    </rtps>
  </participant>
  <data_writer profile_name="es_dm_writer" is_default_profile="true">
    <times>
      <heartbeatPeriod><sec>0</sec><nanosec>{heartbeat_ns}</nanosec></heartbeatPeriod>
    </times>
  </data_writer>
</profiles>
"""


def write_profile(directory: Path, segment_bytes: int = SHM_SEGMENT_BYTES) -> Path:
    """Write the profile into ``directory`` (atomically, shared by processes); return its path.

    Raises:
        OSError: the directory cannot be created or written.
        ValueError: ``segment_bytes`` is not positive.

    """
    text = profile_xml(segment_bytes)
    directory.mkdir(mode=0o777, parents=True, exist_ok=True)
    path = directory / f"fastdds_shm_{segment_bytes}_hb_{round(HEARTBEAT_PERIOD_S * 1e3)}ms.xml"
    if path.exists() and path.read_text(encoding="utf-8") == text:
        return path
    partial = directory / f".{path.name}.{os.getpid()}"
    partial.write_text(text, encoding="utf-8")
    partial.replace(path)
    return path


def configure_middleware(directory: Path | None = None) -> Path | None:
    """Make this process's Fast DDS use the es_dm profile (call before ``rclpy.init``).

    Args:
        directory: where the profile is written (default: ``es_dm_fastdds`` in the
            temporary directory).

    Returns:
        The profile now in use, or ``None`` when the environment names a profile already,
        another RMW is chosen, or the profile could not be written (said on stderr; Fast
        DDS's defaults then apply).

    """
    if os.environ.get(PROFILES_VARIABLE):
        return None
    rmw = os.environ.get("RMW_IMPLEMENTATION", "")
    if rmw and rmw not in FASTDDS_RMWS:
        return None
    try:
        path = write_profile(directory or Path(tempfile.gettempdir()) / "es_dm_fastdds")
    except OSError as err:
        print(f"warning: Fast DDS profile not written ({err}): the default shared-memory "
              "segment (512 KiB) stays", file=sys.stderr)
        return None
    os.environ[PROFILES_VARIABLE] = str(path)
    return path
