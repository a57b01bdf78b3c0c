"""The layering rules of the source tree, checked from the files themselves (ast, nothing imported).

Layers, lowest first (a module imports only its own layer or lower ones):
  0  common (contract, codecs, bus, runtime, services table), world (court, camera, angles), models (data)
  1  libraries: scan (the radial scan), localizer (the runtime localizer), shot (ballistics, RPM)
  2  stages: services/<stage> (config, service, entry point); a stage never imports another stage
  3  tools (courtloc/: CLI, launcher, pit tools, benches) and the lab (lab/, sim/ the twin, training/)
Nothing on the robot side (layers 0-2) imports the twin, the lab or training, not even inside a function
(the simulated camera is the twin's own camera stage, sim/camera_stage.py).
No import circles among module-level imports. A function-local import is allowed only for an optional
heavy dependency (torch and what imports it, matplotlib, tqdm, foxglove, rosbags, websockets), and it
carries a `#` comment saying why.
"""
from __future__ import annotations

import ast
from dataclasses import dataclass
from pathlib import Path

ROOT = "courtloc"
LAYERS: dict[str, int] = {
    "common": 0, "world": 0, "models": 0,
    "scan": 1, "localizer": 1, "shot": 1,
    "services": 2,
    "lab": 3, "sim": 3, "training": 3, "": 3,  # "": the tools directly under courtloc/
}
ROBOT_SIDE = ("common", "world", "models", "scan", "localizer", "shot", "services")
OPTIONAL_HEAVY = {"torch", "torchvision", "matplotlib", "tqdm", "foxglove", "rosbags", "websockets"}
OFF_ROBOT = ("sim", "lab", "training")  # what the robot side never imports: not lazily, not by name
# (importer, third-party module): a lazy import of a required dependency the rules allow, with why.
ALLOWED_LAZY_EXTERNAL = {
    ("courtloc.doctor", "cv2"): "the doctor reports a broken OpenCV install instead of dying with it",
    ("courtloc.doctor", "onnxruntime"): "the doctor reports a broken onnxruntime install instead of dying with it",
    # scipy costs ~0.8 s to import; every process that reads a deployment imports the shooter's config
    ("courtloc.shot.ballistics", "scipy.optimize"): "only solving a shot or fitting drag needs it",
    ("courtloc.shot.rpm", "scipy.interpolate"): "only a measured RPM table needs it",
}


@dataclass(frozen=True)
class Import:
    importer: str
    imported: str
    path: Path
    line: int
    local: bool  # inside a function
    type_only: bool  # under `if TYPE_CHECKING:`
    commented: bool  # a `#` comment on its line or the line above


def package_of(module: str) -> str:
    """'courtloc.services.infer.engine' -> 'services'; a tool under courtloc/ -> ''."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 and parts[1] in LAYERS else ""


def stage_of(module: str, stages: set[str]) -> str | None:
    """'courtloc.services.infer.engine' or the stage package 'courtloc.services.infer' -> 'infer'; None for
    a module that is no stage's (`stages`: the stage packages, courtloc.services.<folder>)."""
    parts = module.split(".")
    return parts[2] if len(parts) > 2 and ".".join(parts[:3]) in stages else None


def module_files(repo: Path, package_dirs: dict[str, str]) -> dict[str, Path]:
    """Import name -> file, from the package-dir mapping (import prefix -> folder)."""
    found: dict[str, Path] = {}
    for prefix, folder in package_dirs.items():
        base = repo / folder
        for path in base.rglob("*.py"):
            parts = [p for p in path.relative_to(base).with_suffix("").parts if p != "__init__"]
            found[".".join([prefix, *parts])] = path
    return found


def imports_of(module: str, path: Path) -> list[Import]:
    source = path.read_text()
    lines = source.splitlines()
    tree = ast.parse(source)
    parents: dict[ast.AST, ast.AST] = {}
    for node in ast.walk(tree):
        for child in ast.iter_child_nodes(node):
            parents[child] = node

    def context(node: ast.AST) -> tuple[bool, bool]:
        local = type_only = False
        parent = parents.get(node)
        while parent is not None:
            if isinstance(parent, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
                local = True
            if isinstance(parent, ast.If) and "TYPE_CHECKING" in ast.unparse(parent.test):
                type_only = True
            parent = parents.get(parent)
        return local, type_only

    is_package = path.name == "__init__.py"
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = module.split(".")[: len(module.split(".")) - node.level + (1 if is_package else 0)]
                stem = ".".join(base + ([node.module] if node.module else []))
            else:
                stem = node.module or ""
            # `from pkg import sub` imports the submodule when there is one: both are recorded
            targets = [stem, *(f"{stem}.{alias.name}" for alias in node.names if stem.startswith(ROOT + "."))]
        elif (named := _imported_by_name(node)) is not None:  # importlib.import_module("courtloc....")
            targets = [named]
        else:
            continue
        local, type_only = context(node)
        here = lines[node.lineno - 1]
        above = lines[node.lineno - 2] if node.lineno > 1 else ""
        commented = "#" in here or above.strip().startswith("#")
        for target in targets:
            found.append(Import(module, target, path, node.lineno, local, type_only, commented))
    return found


def _imported_by_name(node: ast.AST) -> str | None:
    """The module of `importlib.import_module("courtloc.x")` or `__import__("courtloc.x")` (a literal name of
    ours): an import all the same, checked by the same rules."""
    if not (isinstance(node, ast.Call) and node.args and isinstance(node.args[0], ast.Constant)):
        return None
    name = node.args[0].value
    func = ast.unparse(node.func)
    if func.split(".")[-1] in ("import_module", "__import__") and isinstance(name, str) and name.startswith(ROOT + "."):
        return name
    return None


def violations(repo: Path, package_dirs: dict[str, str]) -> list[str]:
    files = module_files(repo, package_dirs)
    all_imports = [imp for name, path in files.items() for imp in imports_of(name, path)]
    internal = [i for i in all_imports if i.imported in files]
    stages = {name for name, path in files.items()
              if path.name == "__init__.py" and len(name.split(".")) == 3 and package_of(name) == "services"}
    torch_modules = {i.importer for i in all_imports
                     if not i.local and not i.type_only and i.imported.split(".")[0] == "torch"}
    problems: list[str] = []
    for imp in internal:
        where = f"{imp.path.relative_to(repo)}:{imp.line}"
        if imp.importer == imp.imported:
            continue
        a, b = package_of(imp.importer), package_of(imp.imported)
        if LAYERS[b] > LAYERS[a]:
            problems.append(f"{where}: {imp.importer} (layer {LAYERS[a]}) imports {imp.imported} (layer {LAYERS[b]})")
        sa, sb = stage_of(imp.importer, stages), stage_of(imp.imported, stages)
        if sa is not None and sb is not None and sa != sb:
            problems.append(f"{where}: stage {sa} imports stage {sb} ({imp.imported})")
        if a in ROBOT_SIDE and b in OFF_ROBOT:  # at import time, in a function or under TYPE_CHECKING alike
            problems.append(f"{where}: robot-side {imp.importer} imports {imp.imported}")
        if imp.local and imp.imported not in torch_modules:
            problems.append(f"{where}: function-local import of {imp.imported} in {imp.importer}")
        elif imp.local and not imp.commented:
            problems.append(f"{where}: function-local import of {imp.imported} without a comment saying why")
    for imp in all_imports:
        top = imp.imported.split(".")[0]
        if imp.local and top != ROOT:
            where = f"{imp.path.relative_to(repo)}:{imp.line}"
            if top not in OPTIONAL_HEAVY and (imp.importer, imp.imported) not in ALLOWED_LAZY_EXTERNAL:
                problems.append(f"{where}: function-local import of {imp.imported} in {imp.importer}")
            elif not imp.commented:
                problems.append(f"{where}: function-local import of {imp.imported} without a comment saying why")
    problems += [f"import circle: {' -> '.join(cycle)}" for cycle in cycles(internal)]
    return sorted(set(problems))


def cycles(imports: list[Import]) -> list[list[str]]:
    """Circles among module-level imports (what runs at import time), one per strongly connected set."""
    graph: dict[str, set[str]] = {}
    for imp in imports:
        if not imp.local and not imp.type_only and imp.importer != imp.imported:
            graph.setdefault(imp.importer, set()).add(imp.imported)
            graph.setdefault(imp.imported, set())
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []
    counter = [0]

    def visit(node: str) -> None:  # Tarjan's strongly connected components
        index[node] = low[node] = counter[0]
        counter[0] += 1
        stack.append(node)
        on_stack.add(node)
        for nxt in sorted(graph[node]):
            if nxt not in index:
                visit(nxt)
                low[node] = min(low[node], low[nxt])
            elif nxt in on_stack:
                low[node] = min(low[node], index[nxt])
        if low[node] == index[node]:
            component = []
            while True:
                member = stack.pop()
                on_stack.discard(member)
                component.append(member)
                if member == node:
                    break
            # a package importing its own submodule (`from pkg import sub`) is not a circle
            members = [m for m in component if not any(o != m and o.startswith(m + ".") for o in component)]
            if len(members) > 1:
                found.append(sorted(members))

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return found
