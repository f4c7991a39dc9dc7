"""Run every benchmark section and print its table."""

from __future__ import annotations

import importlib
import pkgutil
import sys
import time
from pathlib import Path


def main(argv: list[str]) -> int:
    here = Path(__file__).parent
    names = sorted(m.name for m in pkgutil.iter_modules([str(here)]) if m.name.startswith("bench_"))
    if argv:
        names = [n for n in names if any(a in n for a in argv)]
    for name in names:
        mod = importlib.import_module(f"bench.{name}")
        title = (mod.__doc__ or name).strip().splitlines()[0]
        print(f"\n== {title} ==", flush=True)
        t0 = time.perf_counter()
        mod.main()
        print(f"   ({name}: {time.perf_counter() - t0:.1f} s)", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
