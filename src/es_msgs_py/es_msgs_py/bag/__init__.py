"""Read and write rosbag2 bags of the es_dm contract (pure: rosbags and numpy, no rclpy).

Bags are rosbag2 directories (``metadata.yaml`` + storage files, MCAP by default or
sqlite3) written with the ``rosbags`` library, so ROS 2 Jazzy tools read them. One module
per concern:

- :mod:`~es_msgs_py.bag.writer`: :class:`BagWriter`, :func:`write_array_bag`;
- :mod:`~es_msgs_py.bag.reader`: :func:`read_bag`, :class:`TopicSeries`, and the table of
  storage plugins (:mod:`~es_msgs_py.bag.storage_mcap`,
  :mod:`~es_msgs_py.bag.storage_sqlite3`) that read a killed writer's bag too;
- :mod:`~es_msgs_py.bag.codec`: ``Float64MultiArray`` grids/sensors <-> CDR with numpy;
- :mod:`~es_msgs_py.bag.errors`: :class:`BagError` (a ``ValueError``) and its subclasses.
"""

from es_msgs_py.bag.codec import (
    COL_LABEL,
    FLOAT64_MULTI_ARRAY,
    ROW_LABEL,
    SENSOR_LABEL,
    FloatArray,
    decode_float64_multi_arrays,
    encode_float64_multi_array,
)
from es_msgs_py.bag.errors import (
    BagError,
    BagExistsError,
    BagLayoutError,
    BagNotFoundError,
    BagWriteError,
    CorruptBagError,
    MissingTopicError,
    NotABagError,
    UnknownMessageTypeError,
    UnsupportedBagError,
)
from es_msgs_py.bag.reader import STORAGE_PLUGINS, TopicSeries, read_bag
from es_msgs_py.bag.writer import (
    BAG_VERSION,
    STORAGES,
    BagWriter,
    Storage,
    ros_type_name,
    write_array_bag,
)

__all__ = [
    "BAG_VERSION",
    "COL_LABEL",
    "FLOAT64_MULTI_ARRAY",
    "ROW_LABEL",
    "SENSOR_LABEL",
    "STORAGES",
    "STORAGE_PLUGINS",
    "BagError",
    "BagExistsError",
    "BagLayoutError",
    "BagNotFoundError",
    "BagWriteError",
    "BagWriter",
    "CorruptBagError",
    "FloatArray",
    "MissingTopicError",
    "NotABagError",
    "Storage",
    "TopicSeries",
    "UnknownMessageTypeError",
    "UnsupportedBagError",
    "decode_float64_multi_arrays",
    "encode_float64_multi_array",
    "read_bag",
    "ros_type_name",
    "write_array_bag",
]
