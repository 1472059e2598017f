"""Import open3d without its plotly drawing module until that is used (the lab's modules import open3d; the
server does not: graspd reads cloud files with numpy).

`import open3d` imports open3d.visualization, whose draw_plotly module imports dash and plotly at once:
about half a second of every process that only needs open3d's geometry (meshes, raycasting, file reading).
defer_plotly_drawing(), which graspd_lab/__init__.py calls before any lab module imports open3d, puts a
stand-in for that module in sys.modules; its three functions load the real module on first call, so
open3d.visualization.draw_plotly(...) and friends keep working."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType
from typing import Any

_NAME = "open3d.visualization.draw_plotly"
_FUNCTIONS = ("get_plotly_fig", "draw_plotly", "draw_plotly_server")


def _real_module() -> ModuleType:
    """open3d's own draw_plotly module, loaded from its file under a private name (once)."""
    name = "open3d.visualization._draw_plotly_deferred"
    if name in sys.modules:
        return sys.modules[name]
    import open3d.visualization as vis  # noqa: PLC0415  (open3d is loaded when its drawing is used)

    spec = importlib.util.spec_from_file_location(name, Path(vis.__file__).parent / "draw_plotly.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


def _forward(function: str) -> Any:
    def call(*args: Any, **kwargs: Any) -> Any:
        return getattr(_real_module(), function)(*args, **kwargs)

    call.__name__ = call.__qualname__ = function
    call.__doc__ = f"open3d.visualization.{function}, loaded on first call (graspd_lab.open3d_import)."
    return call


def _other_attribute(attr: str) -> Any:
    """Any other public name of the real module (dunder names are the import system's probes: not forwarded)."""
    if attr.startswith("__"):
        raise AttributeError(attr)
    return getattr(_real_module(), attr)


def defer_plotly_drawing() -> bool:
    """Install the stand-in unless open3d is already imported (or not installed, or laid out differently);
    True when it is in place.  Idempotent."""
    if sys.modules.get(_NAME) is not None:
        return getattr(sys.modules[_NAME], "__graspd_deferred__", False)
    if "open3d" in sys.modules:
        return False
    spec = importlib.util.find_spec("open3d")
    if spec is None or spec.origin is None:
        return False
    if not (Path(spec.origin).parent / "visualization" / "draw_plotly.py").is_file():
        return False
    stand_in = ModuleType(_NAME, "open3d's draw_plotly, loaded on first use (graspd_lab.open3d_import)")
    for function in _FUNCTIONS:
        setattr(stand_in, function, _forward(function))
    stand_in.__getattr__ = _other_attribute  # type: ignore[method-assign]
    stand_in.__graspd_deferred__ = True  # type: ignore[attr-defined]
    sys.modules[_NAME] = stand_in
    return True
