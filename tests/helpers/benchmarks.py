"""Loading a benchmark script (benchmarks/ has no package) as a module for its tests."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

BENCHMARKS = Path(__file__).resolve().parents[2] / "benchmarks"


def load_benchmark(relpath: str, name: str) -> ModuleType:
    """benchmarks/``relpath`` as the module ``name`` (registered in ``sys.modules``, so that its dataclasses and
    pickles resolve); benchmarks/ goes on ``sys.path`` for the scripts that import their siblings."""
    if str(BENCHMARKS) not in sys.path:
        sys.path.insert(0, str(BENCHMARKS))
    spec = importlib.util.spec_from_file_location(name, BENCHMARKS / relpath)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod
    spec.loader.exec_module(mod)
    return mod
