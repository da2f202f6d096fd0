"""Import lab recordings (MATLAB, HDF5, CSV/TSV, NumPy) into contract bags (pure, no rclpy).

:func:`import_recording` with a map from :func:`load_map`; the CLI is
:mod:`es_recordings.labimport.cli` (``ros2 run es_msgs_py import``).
"""

from es_recordings.labimport.errors import LabImportError, MapError, SourceError
from es_recordings.labimport.importer import ImportSummary, TopicSummary, import_recording
from es_recordings.labimport.mapfile import ImportMap, load_map, parse_map

__all__ = [
    "ImportMap",
    "ImportSummary",
    "LabImportError",
    "MapError",
    "SourceError",
    "TopicSummary",
    "import_recording",
    "load_map",
    "parse_map",
]
