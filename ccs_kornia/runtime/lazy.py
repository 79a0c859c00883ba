"""Lazy package exports (PEP 562): a name is imported from its module on first access, not at package import.

So ``import ccs_kornia.geometry.camera`` loads neither the stages nor OpenCV, and ``import ccs_kornia.modules`` loads no
stage until one is used.

Example:
    >>> import sys
    >>> __getattr__, __dir__ = lazy_exports("ccs_kornia", {"CalibrationPipeline": "ccs_kornia.pipeline.calibration_pipeline"})
    >>> __getattr__("CalibrationPipeline").__name__, "ccs_kornia.pipeline.calibration_pipeline" in sys.modules
    ('CalibrationPipeline', True)
"""

from __future__ import annotations

import importlib
import sys
from typing import Any, Callable

__all__ = ["lazy_exports"]


def lazy_exports(package: str, exports: dict[str, str]) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """Module ``__getattr__`` and ``__dir__`` that resolve ``exports`` (name -> defining module) on first access.

    Args:
        package: the package's ``__name__``.
        exports: public name -> module that defines it.

    Returns:
        ``(__getattr__, __dir__)`` to assign in the package's ``__init__``.
    """

    def __getattr__(name: str) -> Any:
        if name not in exports:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(exports[name]), name)
        setattr(sys.modules[package], name, value)  # later look-ups skip __getattr__
        return value

    def __dir__() -> list[str]:
        return sorted(set(vars(sys.modules[package])) | set(exports))

    return __getattr__, __dir__
