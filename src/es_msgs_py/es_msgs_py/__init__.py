"""The es_dm interface contract in code: topics, QoS, array layouts, diagnostics and bags.

See ``shared/docs/interfaces.md``; every node and tool of the suite goes through this package
so that data from a real test stand can replace the simulator at any point.
"""

__version__ = "0.1.0"
