"""Imports that two threads of one process may ask for at once, done one at a time.

Python resolves an import cycle between two threads by handing one of them a partly initialised module. SciPy's
subpackages import each other in a cycle, so a node that preloads them in a background thread while a callback
imports them on first use can fail with "cannot import name ... from partially initialized module". Every import
that may run in such a race goes through ``import_serialized`` and its one process-wide lock.

A module that cannot be imported is a ``VesselError`` naming it and the fix, for the node to print as one line.
"""

from __future__ import annotations

import importlib
import threading
from types import ModuleType

from vessel_common.errors import VesselError

_IMPORT_LOCK = threading.RLock()


def import_serialized(name: str) -> ModuleType:
    """``importlib.import_module(name)``, never at the same time as another ``import_serialized``."""
    with _IMPORT_LOCK:
        try:
            return importlib.import_module(name)
        except Exception as error:  # whatever the module raised while it was imported
            raise VesselError(f"cannot import {name} ({type(error).__name__}: {error}): install the requirements "
                              "with ./vessel setup") from None
