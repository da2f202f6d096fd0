"""The lazy public face of a package (PEP 562): its modules load on first access.

A package's ``__init__`` lists its public modules in ``__all__`` and sets
``__getattr__ = lazy_modules(__name__, __all__)`` under ``if not TYPE_CHECKING:``; its
``if TYPE_CHECKING:`` imports let type checkers see the modules (and flag a misspelt name,
which they would accept if they saw a module-level ``__getattr__``). Importing the package
then costs nothing of its modules: ``import es_physics`` loads no numpy, and a node's package
loads no rclpy until a ROS module is used.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Iterable
from types import ModuleType

__all__ = ["lazy_modules"]


def lazy_modules(package: str, public: Iterable[str]) -> Callable[[str], ModuleType]:
    """Return the module ``__getattr__`` that imports ``package``'s public modules on access.

    Args:
        package: the package's dotted name (its ``__name__``).
        public: the package's public names (its ``__all__``); dunder names such as
            ``__version__`` are attributes the package defines itself, not modules.

    Returns:
        ``__getattr__(name)``: the module ``package.name`` (imported once; Python then keeps
        it as an attribute of the package).

    """
    modules = frozenset(name for name in public if not name.startswith("__"))

    def public_module(name: str) -> ModuleType:
        """Import a public module of the package on first access.

        Raises:
            AttributeError: ``name`` is not a public module of the package.

        """
        if name in modules:
            return importlib.import_module(f"{package}.{name}")
        raise AttributeError(f"module {package!r} has no attribute {name!r}")

    return public_module
