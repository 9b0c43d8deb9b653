"""The library is a library: importing any stepzoo module leaves JAX's configuration and
XLA_FLAGS as they were, and no module imports a layer above its own (the order of
docs/design.md: shared plumbing, dynamics, integrators, then bench and search as siblings,
reports, the workflows, and the command line on top); no command module imports another."""
import ast
import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = {"stepzoo": "stepzoo", "dynamics": "stepzoo.dynamics",
            "integrators": "stepzoo.integrators", "bench": "stepzoo.bench",
            "search": "stepzoo.search", "reports": "stepzoo.reports"}
# Layer of each package; the workflows (stepzoo/workflows/) sit above the library and the
# command line (stepzoo/cli/, __main__) above all.
LAYER = {"stepzoo": 0, "stepzoo.dynamics": 1, "stepzoo.integrators": 2, "stepzoo.bench": 3,
         "stepzoo.search": 3, "stepzoo.reports": 4, "stepzoo.workflows": 5}
COMMAND_LINE = 6


def _modules(folder: str) -> list[Path]:
    """Every module of a top-level folder, its subpackages' included (bench/perf, the
    development benchmarks, is not part of the library)."""
    return [p for p in sorted((ROOT / folder).rglob("*.py"))
            if "perf" not in p.relative_to(ROOT).parts]

IMPORT_ALL = """
import importlib, json, os, pkgutil
import jax
def settings():
    return [jax.config.jax_enable_x64, jax.config.jax_platforms, os.environ.get("XLA_FLAGS")]
before = settings()
names = []
for package in %r:
    pkg = importlib.import_module(package)
    for info in pkgutil.walk_packages(pkg.__path__, package + "."):
        if not info.ispkg and info.name != "stepzoo.__main__" and ".perf" not in info.name:
            importlib.import_module(info.name)
            names.append(info.name)
print(json.dumps({"before": before, "after": settings(), "names": names}))
"""


def test_importing_every_module_changes_no_jax_setting_nor_xla_flags(tmp_path):
    env = {k: v for k, v in os.environ.items() if not k.startswith("JAX_")}
    env["XLA_FLAGS"] = "--xla_cpu_enable_fast_math=false"
    packages = [*PACKAGES.values(), "stepzoo.cli", "stepzoo.workflows"]
    proc = subprocess.run([sys.executable, "-c", IMPORT_ALL % packages],
                          capture_output=True, text=True, cwd=tmp_path, env=env, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    seen = json.loads(proc.stdout.strip().splitlines()[-1])
    assert seen["before"] == [False, None, "--xla_cpu_enable_fast_math=false"], seen["before"]
    assert seen["after"] == seen["before"]
    assert {"stepzoo.integrators.driver", "stepzoo.cli.sweep",
            "stepzoo.search.planner.connection_ocp", "stepzoo.cli.run", "stepzoo.dynamics.models"} <= set(seen["names"])


def _module_layer(folder: str, path: Path) -> tuple[str, int]:
    parts = path.relative_to(ROOT / folder).with_suffix("").parts
    name = ".".join([PACKAGES[folder], *parts])
    if path.stem == "__main__" or name.startswith("stepzoo.cli"):
        return name, COMMAND_LINE
    package = ".".join(name.split(".")[:2])
    return name, LAYER[package if package in LAYER else PACKAGES[folder]]


def _imported(tree: ast.AST) -> set[str]:
    """Every stepzoo package a module imports (at any depth of its code)."""
    found = set()
    for node in ast.walk(tree):
        names = []
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module:
            names = [node.module] + [f"{node.module}.{a.name}" for a in node.names]
        for name in names:
            parts = name.split(".")
            if parts[0] == "stepzoo":
                found.add(".".join(parts[:2]) if ".".join(parts[:2]) in LAYER else "stepzoo")
    return found


def test_no_module_imports_a_layer_above_its_own():
    wrong = []
    for folder in PACKAGES:
        for path in _modules(folder):
            name, own = _module_layer(folder, path)
            if own == COMMAND_LINE:
                continue
            for package in _imported(ast.parse(path.read_text())):
                layer = LAYER[package]
                sibling = own == layer == 3 and not name.startswith(package + ".")
                if layer > own or sibling:
                    wrong.append(f"{name} (layer {own}) imports {package} (layer {layer})")
    assert not wrong, "\n".join(wrong)


def test_no_library_module_imports_the_command_line():
    """The command line sits on top: no module outside stepzoo/cli/ (and __main__) imports
    it, at any depth of its code."""
    wrong = []
    for folder in PACKAGES:
        for path in _modules(folder):
            name, own = _module_layer(folder, path)
            if own == COMMAND_LINE:
                continue
            for node in ast.walk(ast.parse(path.read_text())):
                names = [a.name for a in node.names] if isinstance(node, ast.Import) else \
                    [node.module or ""] + [f"{node.module}.{a.name}" for a in node.names] \
                    if isinstance(node, ast.ImportFrom) else []
                wrong += [f"{name} imports {imported}" for imported in names
                          if imported == "stepzoo.cli" or imported.startswith("stepzoo.cli.")]
    assert not wrong, "\n".join(sorted(set(wrong)))


def test_no_command_module_imports_another():
    """A command module parses its arguments and makes one call into the library or the
    workflows; what two commands share lives below them, not in one of them."""
    wrong = []
    for path in sorted((ROOT / "stepzoo" / "cli").glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else \
                [f"{node.module}.{a.name}" for a in node.names] + [node.module or ""] \
                if isinstance(node, ast.ImportFrom) else []
            wrong += [f"stepzoo/cli/{path.name} imports {n}" for n in names
                      if n.startswith("stepzoo.cli.") and n.split(".")[2] not in
                      ("__init__", path.stem) and (ROOT / "stepzoo" / "cli" /
                                                   f"{n.split('.')[2]}.py").exists()]
    assert not wrong, "\n".join(sorted(set(wrong)))


def test_no_library_folder_holds_more_than_fifteen_modules():
    crowded = {str(d.relative_to(ROOT)): n for folder in PACKAGES
               for d in [ROOT / folder, *(ROOT / folder).rglob("*")] if d.is_dir()
               if (n := len([p for p in d.glob("*.py") if p.name != "__init__.py"])) > 15}
    assert not crowded, crowded


# Libraries that take from a few hundredths of a second to seconds to import, and which
# commands need only once they compute (JAX, SciPy, CasADi), read map files (Pillow, PyYAML)
# or write tables and figures.
HEAVY = ("jax", "scipy", "casadi", "PIL", "yaml", "pandas", "pyarrow", "matplotlib", "plotly",
         "dask", "distributed")
IMPORTED_AFTER = """
import json, sys
from stepzoo.cli import main
try:
    main(sys.argv[1:])
except SystemExit:
    pass
print(json.dumps(sorted({m.split(".")[0] for m in sys.modules} & set(%r))))
"""


def _heavy_imported(code: str, *args) -> list[str]:
    proc = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])


def test_help_of_every_command_imports_no_heavy_library():
    from stepzoo.cli import COMMANDS
    code = IMPORTED_AFTER % (HEAVY,)
    heavy = {name: _heavy_imported(code, name, "--help") for name in ["--help", *COMMANDS]}
    assert heavy == {name: [] for name in heavy}


def test_plan_imports_before_its_search_only_what_it_searches_with():
    """The modules `stepzoo plan` runs before its search (the command, scenarios, config,
    planner) import JAX, SciPy and CasADi, and no table or plotting library."""
    code = ("import json, sys\n"
            "from stepzoo.cli import plan\n"
            "from stepzoo.search.planner import pathfinder, config\n"
            "from stepzoo.search.world import scenarios\n"
            f"print(json.dumps(sorted({{m.split('.')[0] for m in sys.modules}} & set({HEAVY!r}))))")
    assert _heavy_imported(code) == ["casadi", "jax", "scipy"]


def test_test_modules_share_helpers_through_one_module_only():
    """What several test modules use lives in tests/helpers.py: no test module imports
    another test module (nor conftest)."""
    tests = ROOT / "tests"
    modules = {p.stem for p in tests.glob("test_*.py")} | {"conftest"}
    wrong = []
    for path in sorted(tests.glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else \
                [node.module or ""] if isinstance(node, ast.ImportFrom) else []
            wrong += [f"{path.name} imports {n}" for n in names if n.split(".")[0] in modules]
    assert not wrong, "\n".join(wrong)
