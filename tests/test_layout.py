"""The package's layering: imports only go down, and no module uses another's private names."""

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "mjx_emp"

# Bottom first. A module may import modules of its own layer or of layers below it.
LAYERS = [
    ["mjx_emp.errors", "mjx_emp.tracing", "mjx_emp.counters", "mjx_emp.tables", "mjx_emp.shards", "mjx_emp.flip_tables"],
    ["mjx_emp.checks", "mjx_emp.envs.registry"],
    ["mjx_emp.envs.mjx_quiet", "mjx_emp.envs.parts", "mjx_emp.envs.env", "mjx_emp.envs.scripted", "mjx_emp.gce", "mjx_emp.replay",
     "mjx_emp.metrics"],
    ["mjx_emp.rollout.structures", "mjx_emp.rollout.hierarchy", "mjx_emp.rollout.collect", "mjx_emp.rollout.flat"],
    ["mjx_emp.nets"],
    ["mjx_emp.learners.common", "mjx_emp.learners.ddpg", "mjx_emp.learners.goal_space", "mjx_emp.learners.sac"],
    ["mjx_emp.algos.*", "mjx_emp.phase2.config"],  # every algorithm's own folder: adding one needs no line here
    ["mjx_emp.algos.registry", "mjx_emp.phase2.presets"],
    ["mjx_emp.phase2.goal_spaces", "mjx_emp.phase2.latent", "mjx_emp.phase2.build"],
    ["mjx_emp.commands"],
    ["mjx_emp.run.packing", "mjx_emp.run.checkpoint", "mjx_emp.run.store", "mjx_emp.run.loop", "mjx_emp.run.jobs", "mjx_emp.run.evaluate",
     "mjx_emp.run.flips", "mjx_emp.run.tracking",
     "mjx_emp.run.seeds", "mjx_emp.run.devices", "mjx_emp.run.hosts", "mjx_emp.run.preflight", "mjx_emp.run.rows",
     "mjx_emp.run.provenance", "mjx_emp.run.specs", "mjx_emp.run.sweep", "mjx_emp.run.noise", "mjx_emp.run.throughput",
     "mjx_emp.run.compile_cache"],
    ["mjx_emp.viz.gl", "mjx_emp.viz.plots", "mjx_emp.viz.render", "mjx_emp.viz.flips"],
    ["mjx_emp.report_stats", "mjx_emp.blocks", "mjx_emp.report"],
    ["mjx_emp.handlers"],
    ["mjx_emp.cli", "mjx_emp.api"],
]
NAMED = {module: depth for depth, modules in enumerate(LAYERS) for module in modules if not module.endswith("*")}
FOLDERS = {module[:-1]: depth for depth, modules in enumerate(LAYERS) for module in modules if module.endswith("*")}


def layer_of(module: str) -> int | None:
    """The layer of a module: its own entry, else the folder entry (``pkg.*``) it falls under."""
    if module in NAMED:
        return NAMED[module]
    return next((depth for folder, depth in FOLDERS.items() if module.startswith(folder)), None)


def module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def package_modules() -> list[Path]:
    return [p for p in PACKAGE.rglob("*.py") if p.name != "__init__.py"]


LAYER_OF = {module_name(p): layer_of(module_name(p)) for p in package_modules()}


def imports(path: Path) -> list[tuple[str, list[str]]]:
    """(module, imported names) of every import in ``path``, function-local ones included."""
    found = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("mjx_emp"):
            names = [alias.name for alias in node.names]
            submodules = [f"{node.module}.{n}" for n in names if f"{node.module}.{n}" in LAYER_OF]
            found += [(m, []) for m in submodules] or [(node.module, names)]
        elif isinstance(node, ast.Import):
            found += [(alias.name, []) for alias in node.names if alias.name.startswith("mjx_emp")]
    return found


def test_every_module_has_a_layer():
    assert not [module for module, depth in LAYER_OF.items() if depth is None]
    assert not [module for module in NAMED if module not in LAYER_OF], "a named module that does not exist"


def test_imports_only_go_down_the_layers():
    upward = [
        f"{module_name(p)} imports {target}"
        for p in package_modules()
        for target, _ in imports(p)
        if LAYER_OF[target] > LAYER_OF[module_name(p)]
    ]
    assert not upward, upward


def import_cycles() -> list[list[str]]:
    """Every circle of imports among the package's modules (function-local imports included),
    each as the list of modules it passes through."""
    graph = {module_name(p): {target for target, _ in imports(p) if target in LAYER_OF and target != module_name(p)}
             for p in package_modules()}
    cycles, done = [], set()

    def visit(module: str, path: list[str]) -> None:
        if module in path:
            cycles.append(path[path.index(module):] + [module])
            return
        if module in done:
            return
        for target in sorted(graph[module]):
            visit(target, path + [module])
        done.add(module)

    for module in sorted(graph):
        visit(module, [])
    return cycles


def test_no_two_modules_import_each_other_even_within_a_layer():
    assert not import_cycles(), import_cycles()


def test_no_module_imports_another_modules_private_names():
    sources = package_modules() + [*ROOT.glob("tests/*.py"), *ROOT.glob("benchmarks/*.py")]
    private = [
        f"{p.relative_to(ROOT)}: {name} from {target}"
        for p in sources
        for target, names in imports(p)
        for name in names
        if name.startswith("_") and name != "__version__"
    ]
    assert not private, private
