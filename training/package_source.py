"""The package's pure-numpy modules (``python/tcd/<name>.py``) for the training code: one copy of the
skeleton and the forward kinematics for inference and training.

Training loads them from the repository's source tree instead of ``import tcd``: the package's
``__init__`` loads the compiled engine, which is not built where training runs on a GPU (only the
working tree travels there), and training must not depend on which ``tcd`` happens to be installed.
"""
from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

PACKAGE_DIR = Path(__file__).resolve().parents[1] / "python" / "tcd"


def package_module(name: str) -> ModuleType:
    """``python/tcd/<name>.py`` as a module (loaded once). Only for modules that import nothing from
    the package (``fk``)."""
    key = f"training._tcd_{name}"
    if key not in sys.modules:
        spec = importlib.util.spec_from_file_location(key, PACKAGE_DIR / f"{name}.py")
        if spec is None or spec.loader is None:
            raise ImportError(f"cannot load {PACKAGE_DIR / f'{name}.py'}")
        module = importlib.util.module_from_spec(spec)
        sys.modules[key] = module
        spec.loader.exec_module(module)
    return sys.modules[key]
