"""Nothing compiles after the warm-up: the project's numba dispatchers closed to new signatures.

Once `app.live.warmup` has compiled (or loaded from numba's cache) every signature the loop meets,
`close()` turns compiling off in every dispatcher of the project's kernel modules (numba's
`Dispatcher.disable_compile`): a call with argument types the warm-up did not meet then raises
`NotWarmed` at once, naming the kernel and the types, where it would otherwise compile for seconds
to minutes inside the step. A call that matches a compiled signature (numba's safe conversions
included: an int where a float is taken) runs as before. `reopen()` undoes it (for tests).

The dispatchers are every `CPUDispatcher` of the loaded `control`, `app` and `robots` modules after
`KERNEL_MODULES` are imported: the compiled kernels (`control.kernel_registry.KERNELS` and the
helpers they share) and the simulator's own (`app.sim`).
"""

from __future__ import annotations

import importlib
import sys
from typing import Any

# importing these loads every module of the project that defines a compiled kernel
KERNEL_MODULES = ("control.kernel_registry", "app.sim.world", "app.sim.contact", "app.sim.sensor")
PROJECT_PACKAGES = ("control.", "app.", "robots.")


class NotWarmed(TypeError):
    """A compiled kernel was called, after the warm-up, with argument types it was not compiled for."""


def dispatchers() -> dict[str, Any]:
    """Every numba dispatcher of the project's loaded modules (`KERNEL_MODULES` imported first), by
    `module.qualname`."""
    from numba.core.registry import CPUDispatcher

    for name in KERNEL_MODULES:
        importlib.import_module(name)
    out: dict[str, Any] = {}
    for name, module in list(sys.modules.items()):
        if module is None or not name.startswith(PROJECT_PACKAGES):
            continue
        for value in list(vars(module).values()):
            if isinstance(value, CPUDispatcher):
                out[f"{value.py_func.__module__}.{value.py_func.__qualname__}"] = value
    return out


def _short(text: str, width: int = 48) -> str:
    """A type's name cut to `width` characters (a record's runs to kilobytes)."""
    return text if len(text) <= width else text[: width - 1] + "…"


def _refusal(name: str, dispatcher: Any) -> Any:
    """The closed dispatcher's answer to argument types it has no signature for: one NotWarmed."""

    def explain(*args: Any, **kws: Any) -> None:
        types = ", ".join(_short(str(dispatcher.typeof_pyval(a))) for a in args)
        raise NotWarmed(
            f"{name} was not compiled for these argument types in the warm-up and nothing compiles after it: ({types})"
        )

    return explain


def close() -> int:
    """Close every dispatcher (see the module docstring); how many were closed."""
    found = dispatchers()
    for name, dispatcher in found.items():
        dispatcher._can_compile = False  # `disable_compile()`, also for one the warm-up never called
        dispatcher._explain_matching_error = _refusal(name, dispatcher)  # the C dispatcher's callback
    return len(found)


def reopen() -> None:
    """Let every dispatcher compile again (numba's own refusal message back)."""
    for dispatcher in dispatchers().values():
        dispatcher._can_compile = True
        dispatcher.__dict__.pop("_explain_matching_error", None)


def is_closed() -> bool:
    """True when every dispatcher of the project is closed to new signatures."""
    return all(not d._can_compile for d in dispatchers().values())
