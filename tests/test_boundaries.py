"""The arrows between the project's rooms (issue 25), read from the source itself.

- ``artrecon`` (the library that works on any photographs) imports nothing from ``sim`` (the
  simulation harness), at module level or inside a function;
- the ground truth a capture writes beside its images (``ground_truth/``) is opened only by the
  capture that writes it and by the harness's scoring side (scoring, the report's pictures, the
  robustness perturbations that record the error they injected), never by ``artrecon``, the
  robot's plan or the harness's stages;
- no import cycle among the project's modules;
- what does not render loads without an EGL library (pyrender needs one on import).
"""

from __future__ import annotations

import ast
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("artrecon", "sim")

#: The modules that may name the ground-truth folder in code: the writers (the capture of an
#: image set and of the fresh view) and the scoring side.
GROUND_TRUTH_READERS = {"sim.capture.image_set", "sim.capture.fresh", "sim.perturb",
                        "sim.evaluate.scoring", "sim.evaluate.pictures"}


def _modules() -> dict[str, Path]:
    out = {}
    for pkg in PACKAGES:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            parts = list(path.relative_to(ROOT).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join(parts)] = path
    return out


MODULES = _modules()


def _imports(name: str, path: Path) -> set[str]:
    """Project modules that ``name`` imports (anywhere in the file), resolved to module names."""
    tree = ast.parse(path.read_text())
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                up = package.split(".")
                up = up[:len(up) - node.level + 1]
                base = ".".join([*up, base] if base else up)
            # ``from pkg import mod`` depends on the submodule; ``from pkg import name`` on pkg
            targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in MODULES else base
                       for a in node.names]
        else:
            continue
        for t in targets:
            while t and t not in MODULES:
                t = t.rpartition(".")[0]
            if t and t != name:
                out.add(t)
    return out


def _code_strings(path: Path) -> list[str]:
    """String constants of a file that are not docstrings."""
    tree = ast.parse(path.read_text())
    docs = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            body = getattr(node, "body", [])
            if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant):
                docs.add(id(body[0].value))
    return [n.value for n in ast.walk(tree) if isinstance(n, ast.Constant)
            and isinstance(n.value, str) and id(n) not in docs]


def test_the_modules_are_found():
    assert {"artrecon.reconstruct", "sim.evaluate.scoring", "sim.manipulate.planning"} <= set(
        MODULES)


def test_artrecon_imports_nothing_from_sim():
    bad = {name: sorted(i for i in _imports(name, path) if i.split(".")[0] == "sim")
           for name, path in MODULES.items() if name.split(".")[0] == "artrecon"}
    assert not {k: v for k, v in bad.items() if v}


@pytest.mark.parametrize("name", sorted(MODULES))
def test_only_the_scoring_side_names_the_ground_truth(name):
    if name in GROUND_TRUTH_READERS:
        return
    uses = [s for s in _code_strings(MODULES[name]) if "ground_truth" in s]
    assert not uses, f"{name} names the ground truth in code: {uses[:3]}"


def test_the_scoring_side_is_where_the_ground_truth_is_read():
    """The allowed readers do read it (a stale list would let a new reader in unnoticed)."""
    for name in ("sim.capture.image_set", "sim.capture.fresh", "sim.evaluate.scoring"):
        assert any("ground_truth" in s for s in _code_strings(MODULES[name])), name


def test_no_import_cycles():
    graph = {name: _imports(name, path) for name, path in MODULES.items()}
    state: dict[str, int] = {}
    cycles = []

    def visit(n, stack):
        state[n] = 1
        for m in sorted(graph.get(n, ())):
            if state.get(m) == 1:
                cycles.append(stack[stack.index(m):] + [m])
            elif state.get(m) is None:
                visit(m, stack + [m])
        state[n] = 2

    for n in sorted(graph):
        if state.get(n) is None:
            visit(n, [n])
    assert not cycles, cycles[:5]


#: Makes loading any EGL library fail, as on a machine without one (sitecustomize.py).
_NO_EGL = """
import ctypes
_load = ctypes.CDLL.__init__
def _no_egl(self, name, *args, **kwargs):
    if name and "EGL" in str(name):
        raise OSError(f"no {name} (test_boundaries)")
    return _load(self, name, *args, **kwargs)
ctypes.CDLL.__init__ = _no_egl
"""


def test_what_does_not_render_loads_without_egl(tmp_path):
    """sim.evaluate (its --help, the reports), authoring, the perturbations and the texture check
    import sim.render, sim.capture and sim.manipulate only where they render or move the arm."""
    (tmp_path / "sitecustomize.py").write_text(_NO_EGL)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path), str(ROOT)])}
    code = ("import sim.evaluate, sim.evaluate.report, sim.author, sim.perturb, sim.texture_check\n"
            "try:\n    import sim.render\nexcept ImportError:\n    print('no EGL')")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip() == "no EGL"  # the test's EGL is really missing
