"""The effect catalogue: physical effects a base hysteresis model lacks, one class each.

``EFFECTS`` maps each id to its class (built-ins below, plus any loaded with
:func:`load_user_effects`); :func:`get_effect` returns an instance and fails with one line
listing the valid ids.
"""

from __future__ import annotations

import importlib
import importlib.util
import inspect
import pkgutil
import sys
from pathlib import Path

from pmalab.errors import PmalabError
from pmalab.identify.effects.base import Effect

__all__ = ["BUILTIN_IDS", "EFFECTS", "Effect", "EffectError", "get_effect", "load_user_effects"]


class EffectError(PmalabError):
    """An unknown effect id or a broken user effects file."""


# adding an effect is ONE new file in this folder: every module here is imported and every
# Effect subclass with an ``id`` registered
for _m in pkgutil.iter_modules(__path__):
    if not _m.name.startswith("_") and _m.name != "base":
        importlib.import_module(f"{__name__}.{_m.name}")

#: the catalogue's display order (as docs/explanation/physics.md lists it); effects in new files follow, by id
_ORDER = ("viscous-friction", "asymmetric-hysteresis", "nonlinear-stiffness",
          "pressure-variation", "sensor-delay", "inertia", "sensor-drift")


def _builtin() -> list[type[Effect]]:
    found = {c.id: c for c in Effect.__subclasses__() if c.id and c.__module__.startswith(__name__)}
    return sorted(found.values(), key=lambda c: (_ORDER.index(c.id) if c.id in _ORDER else 99, c.id))


#: the catalogue: id -> class (plus any user effects loaded with load_user_effects)
EFFECTS: dict[str, type[Effect]] = {cls.id: cls for cls in _builtin()}
BUILTIN_IDS: tuple[str, ...] = tuple(EFFECTS)


def get_effect(effect_id: str) -> Effect:
    """A fresh instance of the effect ``effect_id`` (PmalabError listing valid ids if unknown)."""
    try:
        return EFFECTS[effect_id]()
    except KeyError:
        raise EffectError(
            f"unknown effect '{effect_id}' (choose from {', '.join(EFFECTS)})"
        ) from None


def load_user_effects(path: str | Path) -> list[str]:
    """Import a user's Python file and register every :class:`Effect` subclass with an ``id``.

    Returns the ids registered (in file order).  A missing file, a file that does not
    import, one without effects, or an effect whose id clashes with a built-in raises one
    :class:`EffectError` line naming the file.
    """
    p = Path(path)
    if not p.is_file():
        raise EffectError(f"{p}: no such effects file")
    mod_name = f"pmalab_user_effects_{abs(hash(str(p.resolve())))}"
    spec = importlib.util.spec_from_file_location(mod_name, p)
    if spec is None or spec.loader is None:
        raise EffectError(f"{p}: not a Python file")
    module = importlib.util.module_from_spec(spec)
    sys.modules[mod_name] = module
    try:
        spec.loader.exec_module(module)
    except Exception as exc:  # a user's file can fail in any way: report it in one line
        sys.modules.pop(mod_name, None)
        line = ""
        tb = exc.__traceback__
        while tb is not None:
            if tb.tb_frame.f_code.co_filename == str(p):
                line = f" (line {tb.tb_lineno})"
            tb = tb.tb_next
        if isinstance(exc, SyntaxError) and exc.lineno:
            line = f" (line {exc.lineno})"
        raise EffectError(f"{p}: could not load effects{line}: {type(exc).__name__}: {exc}") from None
    found: list[str] = []
    for _, obj in inspect.getmembers(module, inspect.isclass):
        if not issubclass(obj, Effect) or obj is Effect or obj.__module__ != mod_name:
            continue
        if not obj.id:
            continue
        if obj.id in BUILTIN_IDS and EFFECTS[obj.id] is not obj:
            raise EffectError(f"{p}: effect class {obj.__name__} reuses the built-in id '{obj.id}'")
        EFFECTS[obj.id] = obj
        found.append(obj.id)
    if not found:
        raise EffectError(f"{p}: defines no Effect subclass with an 'id'")
    # keep the file's order (inspect sorts by name)
    src_order = {name: i for i, name in enumerate(vars(module))}
    found.sort(key=lambda i: src_order.get(EFFECTS[i].__name__, 0))
    return found
