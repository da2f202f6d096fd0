"""What every es_dm package shares below its own layer (layer 0: pure Python, no ROS).

The array type aliases (:mod:`.arrays`: ``FloatArray``, ``BoolArray``, ``IndexArray``,
``IntArray``) and the lazy public face of a package (:mod:`.lazy`: ``lazy_modules``). It
imports nothing of ours, so every package, the ROS-free physics included, may import it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from es_common.lazy import lazy_modules

if TYPE_CHECKING:  # type checkers see the modules; at run time they load on first access
    from es_common import arrays, lazy

__version__ = "0.1.0"

#: The public modules of the package.
__all__ = ["__version__", "arrays", "lazy"]

# Hidden from type checkers, which then flag a misspelt module instead of accepting any name.
if not TYPE_CHECKING:
    __getattr__ = lazy_modules(__name__, __all__)
