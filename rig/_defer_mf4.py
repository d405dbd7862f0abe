"""python-can's MF4 module loads asammdf only when it is used.

``import can`` (and ``import cantools``, which imports ``can``) executes ``can.io.mf4``,
which imports asammdf at once, and asammdf brings pandas, pyarrow and canmatrix: about
0.5 s of CPU, more than the rest of a scenario's start-up together, for python-can's MF4
reader and writer, which a scenario run never uses. This import hook executes
``can.io.mf4`` with asammdf held back (python-can then marks MF4 support as absent) and
makes ``MF4Reader`` and ``MF4Writer`` complete the module on their first use: the module's
code runs again, now with asammdf, which fills in the names their methods look up, and the
class objects everybody already holds stay the same. ``rig export`` uses asammdf directly.

Installed by ``rig/__init__.py``; it does nothing when ``can`` was imported before the rig.
"""

from __future__ import annotations

import importlib.machinery
import importlib.util
import sys
import threading
from collections.abc import Callable, Sequence
from types import ModuleType
from typing import Any

MODULE = "can.io.mf4"
HELD_BACK = "asammdf"
USERS = ("MF4Reader", "MF4Writer")


class _HoldBack:
    """Fails ``import asammdf`` while ``can.io.mf4`` executes the first time (in that thread).
    (The finders and the loader are duck-typed: importlib.abc alone costs 20 ms to import.)"""

    def __init__(self) -> None:
        self.local = threading.local()

    def find_spec(self, name: str, path: Sequence[str] | None,
                  target: ModuleType | None = None) -> importlib.machinery.ModuleSpec | None:
        if getattr(self.local, "active", False) and (
                name == HELD_BACK or name.startswith(HELD_BACK + ".")):
            raise ImportError(f"{HELD_BACK} is loaded on first use (rig._defer_mf4)")
        return None


class _DeferringLoader:
    def __init__(self, loader: Any, hold: _HoldBack) -> None:
        self.loader = loader
        self.hold = hold

    def create_module(self, spec: importlib.machinery.ModuleSpec) -> ModuleType | None:
        return self.loader.create_module(spec)

    def exec_module(self, module: ModuleType) -> None:
        self.hold.local.active = True
        try:
            self.loader.exec_module(module)
        finally:
            self.hold.local.active = False
        if getattr(module, HELD_BACK, None) is None:
            _complete_on_first_use(module, self.loader)


def _complete_on_first_use(module: ModuleType, loader: Any) -> None:
    lock = threading.Lock()
    originals: dict[type, Callable[..., None]] = {}

    def complete() -> None:
        with lock:
            if not originals:
                return  # completed already
            classes = {k: v for k, v in vars(module).items()
                       if isinstance(v, type) and v.__module__ == module.__name__}
            loader.exec_module(module)  # asammdf now imports: the names get their values
            vars(module).update(classes)  # the classes everybody holds stay the ones in use
            for cls, init in originals.items():
                cls.__init__ = init  # type: ignore[misc]
            originals.clear()

    for name in USERS:
        cls = getattr(module, name, None)
        if not isinstance(cls, type):
            continue
        originals[cls] = cls.__init__  # type: ignore[misc]

        def first_init(self: Any, *args: Any, __cls: type = cls, **kwargs: Any) -> None:
            complete()
            __cls.__init__(self, *args, **kwargs)  # type: ignore[misc]

        cls.__init__ = first_init  # type: ignore[misc]


class _Finder:
    def __init__(self, hold: _HoldBack) -> None:
        self.hold = hold

    def find_spec(self, name: str, path: Sequence[str] | None,
                  target: ModuleType | None = None) -> importlib.machinery.ModuleSpec | None:
        if name != MODULE:
            return None
        spec = importlib.machinery.PathFinder.find_spec(name, path)
        if spec is None or spec.loader is None or importlib.util.find_spec(HELD_BACK) is None:
            return spec
        spec.loader = _DeferringLoader(spec.loader, self.hold)
        return spec


def install() -> None:
    """Puts the hook in front of the import system (once; not when can.io.mf4 is loaded)."""
    if MODULE in sys.modules or any(isinstance(f, _Finder) for f in sys.meta_path):
        return
    hold = _HoldBack()
    sys.meta_path[:0] = [hold, _Finder(hold)]
