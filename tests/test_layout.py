"""The package's shape: its parts import each other in one direction only (an explicit order of layers, computed from
the source with `ast`), the leaves import no other part, the LightningModule loads no SfM or LPIPS machinery, and no
module grows past 400 lines. The repository's benchmarks/ too: its files sit in its three roles (speed, quality,
equivalence), none grows past 400 lines, its modules import each other without a cycle, and the package imports
benchmarks/ in one documented place only (`simplenerf benchmark`)."""

from __future__ import annotations

import ast
import subprocess
import sys
from collections import defaultdict
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "simplenerf"
BENCHMARKS = PACKAGE.parent / "benchmarks"
BENCHMARK_ROLES = ("speed", "quality", "equivalence")
MAX_LINES = 400
# The package's only import of benchmarks/ (by importlib, so that an installed package without the repository's
# benchmarks/ says so in one line): the verb `simplenerf benchmark` runs the measurement of benchmarks/speed/.
PACKAGE_IMPORTS_OF_BENCHMARKS = {"simplenerf/commands/benchmark.py": {"benchmarks.speed.training_step"}}

# The parts of the package (a subpackage or a top-level module), lowest first: a part may import only parts of a
# strictly lower layer. A new part must be placed here (test_every_part_has_a_layer).
LAYERS: tuple[tuple[str, ...], ...] = (
    ("errors",),  # the errors the command line prints as one line
    ("geometry", "metrics"),  # leaves
    ("model", "sfm", "synthetic"),  # fields and rendering; structure from motion; the synthetic scene's generator
    ("data",),  # scene formats, splits, batches (sparse depth from sfm, the synthetic scene from synthetic)
    ("method",),  # SimpleNeRF's augmentations, reliability masks, losses; the LightningModule and its optimiser
    ("viz",),  # pictures, videos, geometry export
    ("viewer",),  # the web viewer (its command: commands/view.py)
    ("evaluation",),  # the evaluation protocol
    ("reporting",),  # tables of results
    ("run",),  # the run machinery: the LightningCLI, checks, resume, lock, signals, console, loggers, callbacks
    ("experiments",),  # sweeps of runs
    ("commands",),  # the command line: the verbs and their dispatcher
    ("__main__",),
)
# The run package's own parts (`simplenerf.run.<part>`), lowest first, under the same rule.
RUN_LAYERS: tuple[tuple[str, ...], ...] = (
    ("signals", "memory", "loggers", "hardware"),  # SIGINT/SIGTERM; the allocator; W&B; the CPU and precision
    ("console", "checks", "resume", "lock"),  # one-line errors (a stop by a signal); pre-flight; run records; the lock
    ("callbacks", "config_files"),  # every callback a run uses (RunRecord from resume); the config files given
    ("cli",),  # the LightningCLI
)
# Parts that import no other part of the package at all.
LEAVES = ("geometry", "metrics")


def part_of(module: str) -> str:
    """The part `simplenerf.<part>[.<...>]` of a dotted module name."""
    return module.split(".")[1]


def is_module(dotted: str) -> bool:
    path = PACKAGE.parent.joinpath(*dotted.split("."))
    return path.with_suffix(".py").is_file() or (path / "__init__.py").is_file()


def imported_modules(file: Path, top: str = "simplenerf") -> set[str]:
    """Every module of the package `top` (simplenerf, benchmarks) that `file` imports (also inside functions and
    TYPE_CHECKING blocks, and by `importlib.import_module("<a literal name>")`)."""
    parts = file.relative_to(PACKAGE.parent).with_suffix("").parts
    package = parts if file.name == "__init__.py" else parts[:-1]
    out = set()
    for node in ast.walk(ast.parse(file.read_text())):
        if isinstance(node, ast.Import):
            out |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = ".".join([*package[: len(package) - node.level + 1], *([node.module] if node.module else [])])
            # `from simplenerf.run import signals` imports the module simplenerf.run.signals.
            out |= {f"{base}.{a.name}" if is_module(f"{base}.{a.name}") else base for a in node.names}
        elif (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr == "import_module"
              and node.args and isinstance(node.args[0], ast.Constant) and isinstance(node.args[0].value, str)):
            out.add(node.args[0].value)
    return {m for m in out if m.startswith(f"{top}.")}


def import_edges(root: Path = PACKAGE) -> dict[tuple[str, str], list[str]]:
    """(importing part, imported part) -> the files of the importing part that import it; the parts of `root` (the
    package, or a subpackage such as run/)."""
    depth = len(root.relative_to(PACKAGE.parent).parts)
    prefix = ".".join(root.relative_to(PACKAGE.parent).parts) + "."
    edges = defaultdict(list)
    for file in sorted(root.rglob("*.py")):
        if file.parent == root and file.name == "__init__.py":
            continue  # the package's own docstring and version
        source = ".".join(file.relative_to(PACKAGE.parent).with_suffix("").parts).split(".")[depth]
        for module in imported_modules(file):
            if not module.startswith(prefix):
                continue
            target = module.split(".")[depth]
            if target != source:
                edges[(source, target)].append(str(file.relative_to(PACKAGE.parent)))
    return dict(edges)


def all_parts(root: Path = PACKAGE) -> set[str]:
    return {p.stem if p.is_file() else p.name for p in root.iterdir()
            if (p.suffix == ".py" and p.name != "__init__.py") or (p / "__init__.py").is_file()}


def test_every_part_has_a_layer():
    placed = [part for layer in LAYERS for part in layer]
    assert len(placed) == len(set(placed)), "a part is placed twice"
    assert set(placed) == all_parts()


def test_imports_go_down_the_layers_only():
    layer = {part: i for i, parts in enumerate(LAYERS) for part in parts}
    upward = {f"{a} -> {b}": files for (a, b), files in import_edges().items() if layer[b] >= layer[a]}
    assert upward == {}


def test_the_run_package_has_layers_too():
    run = PACKAGE / "run"
    placed = [part for layer in RUN_LAYERS for part in layer]
    assert sorted(placed) == sorted(all_parts(run))
    layer = {part: i for i, parts in enumerate(RUN_LAYERS) for part in parts}
    upward = {f"{a} -> {b}": files for (a, b), files in import_edges(run).items() if layer[b] >= layer[a]}
    assert upward == {}


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """An import cycle of `graph` (node -> the nodes it imports), as the path that closes it, or None."""
    state: dict[str, int] = {}  # 1: on the current path, 2: done

    def cycle_from(node: str, path: list[str]) -> list[str] | None:
        state[node] = 1
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == 1:
                return [*path, node, nxt]
            if nxt not in state and (found := cycle_from(nxt, [*path, node])):
                return found
        state[node] = 2
        return None

    for start in sorted(graph):
        cycle = cycle_from(start, []) if start not in state else None
        if cycle:
            return cycle
    return None


def test_no_two_parts_depend_on_each_other():
    """Independent of LAYERS: the graph of parts has no cycle (a two-way tie is the shortest)."""
    graph = defaultdict(set)
    for a, b in import_edges():
        graph[a].add(b)
    cycle = find_cycle(graph)
    assert cycle is None, "import cycle (after the path to it): " + " -> ".join(cycle)


def test_the_leaves_import_no_other_part():
    assert {(a, b): f for (a, b), f in import_edges().items() if a in LEAVES} == {}


def test_the_graph_sees_imports_inside_functions():
    """The test above would pass vacuously if imports were missed: the verbs' lazy imports are edges."""
    edges = import_edges()
    assert "simplenerf/commands/benchmark.py" in edges[("commands", "run")]  # `simplenerf benchmark`: inside build()
    assert set(edges[("commands", "experiments")]) == {"simplenerf/commands/sweep.py"}  # also inside a function
    assert ("console", "signals") in import_edges(PACKAGE / "run")  # `from simplenerf.run import signals`


def test_importing_the_module_loads_neither_pycolmap_nor_lpips():
    code = "import sys, simplenerf.method.module; print(sorted({'pycolmap', 'lpips'} & set(sys.modules)))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


# What a GPU machine may lack (benchmarks/speed/gpu.sh carries the project's other dependencies as wheels): SfM and
# video writing import them when they run, not when the CLI or a verb's module is imported.
OPTIONAL_AT_IMPORT = ("pycolmap", "av", "wandb")


def test_the_cli_and_the_gpu_scripts_verbs_import_without_pycolmap_av_or_wandb():
    blocked = "; ".join(f"sys.modules[{name!r}] = None" for name in OPTIONAL_AT_IMPORT)
    modules = ("simplenerf.run.cli", "simplenerf.commands.sparse_depth", "simplenerf.commands.benchmark",
               "simplenerf.data.llff", "simplenerf.sfm.sparse_depth", "simplenerf.viz.video")
    code = f"import importlib, sys; {blocked}\nfor m in {modules!r}: importlib.import_module(m)\nprint('ok')"
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=PACKAGE.parent)
    assert result.returncode == 0 and result.stdout == "ok\n", result.stderr


def test_no_module_is_over_400_lines():
    sizes = {str(p.relative_to(PACKAGE)): len(p.read_text().splitlines()) for p in PACKAGE.rglob("*.py")}
    assert {name: n for name, n in sizes.items() if n > MAX_LINES} == {}


def benchmark_files() -> list[Path]:
    return sorted(p for p in BENCHMARKS.rglob("*") if p.suffix in (".py", ".sh") and "__pycache__" not in p.parts)


def test_no_benchmark_file_is_over_400_lines():
    """The size rule over benchmarks/ too, its shell scripts included."""
    files = benchmark_files()
    assert len(files) > 20  # the rule sees the scripts
    sizes = {str(p.relative_to(BENCHMARKS)): len(p.read_text().splitlines()) for p in files}
    assert {name: n for name, n in sizes.items() if n > MAX_LINES} == {}


def test_benchmarks_are_sorted_by_role():
    """Every script of benchmarks/ sits in one of its roles, a package with its own docstring."""
    assert sorted(p.name for p in BENCHMARKS.iterdir() if p.name != "__pycache__") == sorted(
        ["README.md", "__init__.py", *BENCHMARK_ROLES])
    for role in BENCHMARK_ROLES:
        doc = ast.get_docstring(ast.parse((BENCHMARKS / role / "__init__.py").read_text()))
        assert doc and len(doc) > 200, f"benchmarks/{role}/__init__.py: a paragraph on what the role holds"
    assert {p.parent.relative_to(BENCHMARKS).parts[0] for p in benchmark_files() if p.parent != BENCHMARKS} == set(
        BENCHMARK_ROLES)


def benchmark_graph() -> dict[str, set[str]]:
    """benchmarks/ module (`speed.render`) -> the benchmarks/ modules it imports (a package's imports resolved to its
    modules where a `from <package> import <module>` names one)."""
    graph: dict[str, set[str]] = defaultdict(set)
    for file in BENCHMARKS.rglob("*.py"):
        source = ".".join(file.relative_to(BENCHMARKS).with_suffix("").parts).removesuffix(".__init__")
        for module in imported_modules(file, "benchmarks"):
            target = module.removeprefix("benchmarks.")
            if target != source:
                graph[source].add(target)
    return dict(graph)


def test_benchmark_modules_import_each_other_without_a_cycle():
    graph = benchmark_graph()
    # the graph sees the imports it must (a vacuous pass otherwise): module level, inside a function, `from X import Y`
    assert "speed.training_step" in graph["speed.render"] and "speed.training_step" in graph["speed.profile_step"]
    assert {"equivalence.data", "equivalence.layouts", "equivalence.step"} <= graph["equivalence.check"]
    cycle = find_cycle(graph)
    assert cycle is None, "import cycle in benchmarks/: " + " -> ".join(cycle)
    roles = defaultdict(set)
    for a, targets in graph.items():
        roles[a.split(".")[0]] |= {b.split(".")[0] for b in targets} - {a.split(".")[0]}
    cycle = find_cycle(roles)
    assert cycle is None, "the roles of benchmarks/ import each other in a cycle: " + " -> ".join(cycle)


def test_the_package_imports_benchmarks_in_the_documented_place_only():
    found = {str(f.relative_to(PACKAGE.parent)): modules for f in sorted(PACKAGE.rglob("*.py"))
             if (modules := imported_modules(f, "benchmarks"))}
    assert found == PACKAGE_IMPORTS_OF_BENCHMARKS
