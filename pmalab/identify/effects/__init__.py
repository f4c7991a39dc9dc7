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

from pmalab.identify.effects.base import EFFECTS, Effect, EffectError

__all__ = ["BUILTIN_IDS", "EFFECTS", "Effect", "EffectError", "get_effect", "load_user_effects"]


# adding an effect is ONE new file in this folder: every module here is imported and every
# Effect subclass with an ``id`` registered
for _m in pkgutil.iter_modules(__path__):
    if not _m.name.startswith("_") and _m.name != "base":
        importlib.import_module(f"{__name__}.{_m.name}")

#: the built-in catalogue's ids, in their declared order
BUILTIN_IDS: tuple[str, ...] = tuple(EFFECTS)


def get_effect(effect_id: str) -> Effect:
    """A fresh instance of the effect ``effect_id`` (PmalabError listing valid ids if unknown)."""
    return EFFECTS.lookup(effect_id)()


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
        raise EffectError(
            f"{p}: could not load effects{line}: {type(exc).__name__}: {exc}"
        ) from None
    found: list[str] = []
    for _, obj in inspect.getmembers(module, inspect.isclass):
        if not issubclass(obj, Effect) or obj is Effect or obj.__module__ != mod_name:
            continue
        if not obj.id:
            continue
        if obj.id in BUILTIN_IDS and EFFECTS[obj.id] is not obj:
            raise EffectError(f"{p}: effect class {obj.__name__} reuses the built-in id '{obj.id}'")
        EFFECTS.register(obj.id, obj, title=obj.title, order=1000.0, replace=True)
        found.append(obj.id)
    if not found:
        raise EffectError(f"{p}: defines no Effect subclass with an 'id'")
    # keep the file's order (inspect sorts by name)
    src_order = {name: i for i, name in enumerate(vars(module))}
    found.sort(key=lambda i: src_order.get(EFFECTS[i].__name__, 0))
    return found
