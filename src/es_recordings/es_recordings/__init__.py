"""Recordings of the es_dm graph: the recorder node and the lab importer.

:mod:`.record` is the recorder node (``ros2 run es_recordings record``: every /dm topic and
/diagnostics into a rosbag2 bag, stamped at reception); :mod:`.labimport` turns a lab
recording (.mat, .h5/.hdf5, .csv/.tsv, .npz) into a bag of the contract
(``ros2 run es_recordings import``), pure and without rclpy. Bag I/O itself is part of the
contract (:mod:`es_msgs_py.bag`).
"""
