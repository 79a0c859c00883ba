"""The package's layering (docs/architecture.md): what each layer loads, import cycles, dependency rules.

Imports point down only: ``cli`` -> ``commands/`` -> ``outputs/``, ``fleet/`` -> ``pipeline/`` -> ``modules/`` ->
``geometry/`` -> ``runtime/``; ``pipeline/`` reads files through ``io/``, which builds cameras of ``geometry/``; ``training/`` -> ``modules/``, ``losses/``,
``data/``; ``data/`` -> ``geometry/``; nothing in ``modules/`` imports the command line, the pipeline, the outputs,
training, the benchmarks or Lightning, and nothing but the face (``__init__``, ``__main__``, ``cli``) sits at the
package root. The import graph is read from the source with
``ast``; imports inside functions (lazy imports) count as edges like module-level ones, and a lazy package export
(``_EXPORTS`` of a PEP 562 ``__init__``) counts as an edge from the package to the module it names.

Importing ``a.b.c`` also runs the ``__init__`` of ``a`` and ``a.b``; that is not an edge here, because every
``__init__`` of ours imports nothing but :mod:`ccs_kornia.runtime.lazy` (checked below), so running it loads nothing.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "ccs_kornia"


def _module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


MODULES: dict[str, Path] = {_module_name(p): p for p in sorted(PACKAGE.rglob("*.py"))}


def _resolve(module: str, level: int, current: str, is_package: bool) -> str:
    if level == 0:
        return module
    base = current.split(".") if is_package else current.split(".")[:-1]
    base = base[: len(base) - (level - 1)]
    return ".".join(base + ([module] if module else []))


def _edges(name: str, path: Path) -> set[str]:
    """Modules of ours that ``name`` imports (anywhere in the file), plus the targets of lazy exports."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    is_package = path.name == "__init__.py"
    out: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = _resolve(node.module or "", node.level, name, is_package)
            # ``from pkg import sub`` imports the submodule ``pkg.sub`` when there is one
            targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in MODULES else base for a in node.names]
        elif (
            is_package and isinstance(node, ast.Assign) and any(getattr(t, "id", "") == "_EXPORTS" for t in node.targets)
        ):
            targets = [v.value for v in node.value.values]  # type: ignore[attr-defined]
        else:
            continue
        out.update(t for t in targets if t in MODULES and t != name)
    return out


GRAPH: dict[str, set[str]] = {name: _edges(name, path) for name, path in MODULES.items()}


def _external_imports(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out.update(a.name.split(".")[0] for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            out.add(node.module.split(".")[0])
    return out


def _layer(name: str) -> str:
    parts = name.split(".")
    if len(parts) == 1:
        return "package"
    return parts[1]


# ----------------------------------------------------------------------------------------------
# what a layer loads, imported alone
# ----------------------------------------------------------------------------------------------


def _loaded_after(code: str) -> set[str]:
    script = code + "\nimport sys\nprint('\\n'.join(sorted(sys.modules)))\n"
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300,
                          cwd=PACKAGE.parent)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return set(proc.stdout.split())


def _ours(loaded: set[str], *prefixes: str) -> list[str]:
    return sorted(m for m in loaded if any(m == p or m.startswith(p + ".") for p in prefixes))


def test_a_calibration_loads_no_sympy():
    # torch.broadcast_shapes imports torch.fx's symbolic shapes and sympy on first use: 0.4 s of every command-line
    # calibration (runtime.checks.broadcast_shapes is used instead)
    loaded = _loaded_after(
        "import torch\n"
        "from ccs_kornia.geometry.board_points import board_object_points\n"
        "from ccs_kornia.geometry.camera import Camera, project_points\n"
        "from ccs_kornia.geometry.models import FISHEYE, K1K2\n"
        "from ccs_kornia.modules.calibration.solver import CalibrationSolver\n"
        "obj = board_object_points(6, 4, 1.0).double()\n"
        "K = torch.tensor([[400.0, 0, 320], [0, 400, 240], [0, 0, 1]], dtype=torch.float64)\n"
        "rv = torch.tensor([[0.3 * (i % 3 - 1), 0.25 * (i % 2) - 0.1, 0.05 * i] for i in range(6)], dtype=torch.float64)\n"
        "tv = torch.tensor([[-2.5 + 0.2 * i, -1.5, 9.0 + i] for i in range(6)], dtype=torch.float64)\n"
        "uv = project_points(obj.expand(6, -1, -1), K.expand(6, 3, 3), None, rv, tv)\n"
        "for model in (K1K2, FISHEYE):\n"
        "    out = CalibrationSolver(model=model)(uv[None], torch.ones(1, 6, 24, dtype=torch.bool), obj, (640, 480))\n"
        "    assert bool(out.success.all()) and float(out.rms.max()) < 1e-3, (model, out.rms)\n"
        "Camera.from_opencv(FISHEYE, K).project(torch.rand(1, 5, 3, dtype=torch.float64))\n"
    )
    assert "sympy" not in loaded


def test_camera_alone_loads_no_opencv_and_no_stage():
    loaded = _loaded_after("import ccs_kornia.geometry.camera")
    assert "cv2" not in loaded
    assert not _ours(loaded, "ccs_kornia.modules", "ccs_kornia.pipeline", "ccs_kornia.data", "lightning")
    models = [f"ccs_kornia.geometry.models{m}" for m in ("", ".base", ".centred_radial", ".factory", ".fisheye", ".opencv",
                                                        ".splined")]
    assert _ours(loaded, "ccs_kornia") == ["ccs_kornia", "ccs_kornia.geometry", "ccs_kornia.geometry.camera", *models,
                                           "ccs_kornia.runtime", "ccs_kornia.runtime.checks", "ccs_kornia.runtime.lazy"]


def test_modules_load_no_lightning_cli_pipeline_or_training():
    names = sorted(n for n in MODULES if n.startswith("ccs_kornia.modules"))
    loaded = _loaded_after("\n".join(f"import {n}" for n in names))
    assert not _ours(loaded, "lightning", "pytorch_lightning")
    assert not _ours(loaded, *(f"ccs_kornia.{x}" for x in (
        "cli", "commands", "pipeline", "fleet", "outputs", "training", "bench", "data", "losses", "io",
    )))


def test_pipeline_loads_no_lightning():
    names = sorted(n for n in MODULES if n.startswith("ccs_kornia.pipeline"))
    loaded = _loaded_after("\n".join(f"import {n}" for n in names))
    assert not _ours(loaded, "lightning", "pytorch_lightning")
    assert not _ours(loaded, "ccs_kornia.cli", "ccs_kornia.commands", "ccs_kornia.training", "ccs_kornia.bench",
                     "ccs_kornia.fleet", "ccs_kornia.outputs", "ccs_kornia.data")


def test_renderer_does_not_depend_on_the_stages():
    # the ground truth must never come from the stages it is used to test
    loaded = _loaded_after("import ccs_kornia.data.scenes.scenes, ccs_kornia.data.scenes.targets")
    assert not _ours(loaded, "ccs_kornia.modules", "ccs_kornia.pipeline", "ccs_kornia.losses")


# ----------------------------------------------------------------------------------------------
# the import graph
# ----------------------------------------------------------------------------------------------


def test_package_inits_import_nothing_but_the_lazy_helper():
    for name, path in MODULES.items():
        if path.name == "__init__.py":
            direct = {t for t in _edges(name, path) if t not in _lazy_targets(path)}
            assert direct <= {"ccs_kornia.runtime.lazy"}, (name, direct)


def _lazy_targets(path: Path) -> set[str]:
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Assign) and any(getattr(t, "id", "") == "_EXPORTS" for t in node.targets):
            return {v.value for v in node.value.values}  # type: ignore[attr-defined]
    return set()


def test_no_import_cycle():
    state: dict[str, int] = {}  # 1: on the stack, 2: done
    stack: list[str] = []

    def visit(node: str) -> None:
        state[node] = 1
        stack.append(node)
        for nxt in sorted(GRAPH[node]):
            if state.get(nxt) == 1:
                cycle = stack[stack.index(nxt):] + [nxt]
                pytest.fail("import cycle: " + " -> ".join(cycle))
            if nxt not in state:
                visit(nxt)
        stack.pop()
        state[node] = 2

    for name in sorted(GRAPH):
        if name not in state:
            visit(name)


#: layer -> layers of ours it may import (besides itself): the folders, bottom to top
ALLOWED: dict[str, set[str]] = {
    "runtime": set(),
    "package": {"runtime"},
    "geometry": {"runtime"},
    "io": {"geometry", "runtime"},
    "data": {"geometry", "runtime"},
    "losses": {"geometry", "runtime"},
    "modules": {"geometry", "runtime"},
    "pipeline": {"modules", "geometry", "io", "runtime"},
    "outputs": {"pipeline", "modules", "geometry", "io", "runtime"},
    "fleet": {"pipeline", "outputs", "modules", "geometry", "io", "runtime"},
    "training": {"modules", "losses", "data", "geometry", "runtime"},
    "commands": {"outputs", "fleet", "pipeline", "modules", "data", "geometry", "io", "runtime"},
    # the command line dispatches to everything below it; ``bench`` and ``training.cli`` are entry points it
    # forwards to (neither imports the command line)
    "cli": {"commands", "training", "bench", "io", "runtime", "package"},
    "__main__": {"cli"},
    "bench": {"pipeline", "outputs", "modules", "data", "losses", "geometry", "io", "runtime"},
}

#: the only modules at the package root: its face
ROOT_MODULES = {"ccs_kornia", "ccs_kornia.__main__", "ccs_kornia.cli"}


def test_nothing_at_the_package_root_but_its_face():
    root = {n for n in MODULES if n.count(".") == 1 or n == "ccs_kornia"}
    packages = {n for n, p in MODULES.items() if p.name == "__init__.py"}
    assert root - packages == ROOT_MODULES - {"ccs_kornia"}, sorted(root - packages)


def test_dependency_rules():
    problems = []
    for name, targets in GRAPH.items():
        layer = _layer(name)
        assert layer in ALLOWED, f"{name}: no dependency rule for layer {layer!r}"
        for t in targets:
            other = _layer(t)
            if other == layer or (layer == "package" and t in _lazy_targets(MODULES[name])):
                continue
            if other not in ALLOWED[layer]:
                problems.append(f"{name} imports {t}")
    assert not problems, "\n".join(sorted(problems))


def _reachable(start: str) -> set[str]:
    """Modules of ours that ``start`` imports, directly or through others (lazy imports included)."""
    seen, todo = set(), [start]
    while todo:
        for nxt in GRAPH[todo.pop()]:
            if nxt not in seen:
                seen.add(nxt)
                todo.append(nxt)
    return seen


def test_the_correction_stage_stands_below_the_solver():
    # the solver's calibration in the corrected frame (modules/calibration/corrected_frame.py) uses the correction's
    # warp; the correction stage itself (network, warp, pooling) imports nothing of the solver
    for name in (n for n in MODULES if n.startswith("ccs_kornia.modules.correction")):
        assert not _ours(_reachable(name), "ccs_kornia.modules.calibration", "ccs_kornia.modules.detection"), name
    loaded = _loaded_after("\n".join(f"import {n}" for n in MODULES if n.startswith("ccs_kornia.modules.correction")))
    assert not _ours(loaded, "ccs_kornia.modules.calibration", "ccs_kornia.modules.detection")


def test_hand_eye_and_the_rig_are_siblings():
    # both start from the board poses of a held camera and agree on a symmetric board's order
    # (modules/calibration/board_poses.py, board_symmetry.py): neither imports the other
    for name in (n for n in MODULES if n.startswith("ccs_kornia.modules.hand_eye")):
        assert not _ours(_reachable(name), "ccs_kornia.modules.rig"), name
    for name in (n for n in MODULES if n.startswith("ccs_kornia.modules.rig")):
        assert not _ours(_reachable(name), "ccs_kornia.modules.hand_eye"), name


def test_no_stage_imports_lightning_or_the_command_line():
    for name, path in MODULES.items():
        if _layer(name) in ("modules", "pipeline", "camera", "data") and not name.endswith("datamodule"):
            assert not _external_imports(path) & {"lightning", "pytorch_lightning"}, name

