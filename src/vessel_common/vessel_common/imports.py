"""Imports that two threads of one process may ask for at once, done one at a time.

Python resolves an import cycle between two threads by handing one of them a partly initialised module. SciPy's
subpackages import each other in a cycle, so a node that preloads them in a background thread while a callback
imports them on first use can fail with "cannot import name ... from partially initialized module". Every import
that may run in such a race goes through ``import_serialized`` and its one process-wide lock.
"""

from __future__ import annotations

import importlib
import threading
from types import ModuleType

_IMPORT_LOCK = threading.RLock()


def import_serialized(name: str) -> ModuleType:
    """``importlib.import_module(name)``, never at the same time as another ``import_serialized``."""
    with _IMPORT_LOCK:
        return importlib.import_module(name)
