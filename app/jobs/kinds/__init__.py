"""Job kinds of the service. Every module here registers its kinds on
``app.services.jobs.registry.registry``.

Add a kind by adding a module to this package; ``load_kinds()`` imports them all.
"""

from __future__ import annotations

import importlib
import pkgutil

from app.services.jobs.registry import JobRegistry, registry


def load_kinds() -> JobRegistry:
    """Import every module of this package (each registers its kinds); return ``registry``."""
    for module in pkgutil.iter_modules(__path__):
        importlib.import_module(f"{__name__}.{module.name}")
    return registry
