"""What the benchmarks share, in one package.

Settings, records and node processes (:mod:`.benchlib`), the in-process DDS client
(:mod:`.dds_client`), the plain relay node (:mod:`.relay`), the probed node
(:mod:`.probe_node`), CPU and memory hogs (:mod:`.load`) and the report files
(:mod:`.reporting`). The benchmarks themselves are ``bench/bench_*.py`` and
``bench/sections/``; run from bench/ (``bench/run.py``, ``python bench/bench_<x>.py``), Python
finds this package beside them.
"""
