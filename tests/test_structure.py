"""The package's shape (issue 18), checked on the source: layers import only
downwards, no import cycle, one FE driving loop, one atomic writer, one command
codec, small modules and functions."""

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
MAX_MODULE_LINES = 500
MAX_FUNCTION_LINES = 60
# pushplan's layers, lowest first; a module may import from its own layer and those before it
LAYERS = ("errors", "resources", "config", "outputs", "run", "planning", "identify", "mujoco", "drake", "studies", "service",
          "cli")
PEERS = {"studies": {"planning"}, "mujoco": {"planning"}}  # sideways imports allowed
# fe_contact's layers, lowest first
FE_LAYERS = ("linalg", "fem", "contact", "io", "stepping")


def modules(package: str):
    return sorted((ROOT / package).rglob("*.py"))


def module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imported_modules(path: Path) -> set[str]:
    """Absolute names of every module ``path`` imports, at any depth of its code."""
    here = module_name(path).split(".")
    package = here if path.name == "__init__.py" else here[:-1]
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = package[: len(package) - node.level + 1] if node.level else []
            mod = ".".join([*base, *(node.module.split(".") if node.module else [])])
            names.add(mod)
            names.update(f"{mod}.{a.name}" for a in node.names)  # from pkg import submodule
    return names


def layer(name: str, package: str = "pushplan") -> str | None:
    parts = name.split(".")
    return parts[1] if parts[0] == package and len(parts) > 1 else None


@pytest.mark.parametrize("package, layers, peers", [("pushplan", LAYERS, PEERS), ("fe_contact", FE_LAYERS, {})])
def test_layers_import_only_downwards(package, layers, peers):
    wrong = []
    for path in modules(package):
        own = layer(module_name(path), package)
        for name in imported_modules(path):
            other = layer(name, package)
            if own in layers and other in layers:
                if layers.index(other) > layers.index(own) and other not in peers.get(own, ()):
                    wrong.append(f"{module_name(path)} imports {name}")
    assert not wrong, "\n".join(wrong)


def test_fe_contact_is_in_layers():
    # every module of fe_contact lives in one of its layers (the package's own __init__ aside)
    loose = [module_name(p) for p in modules("fe_contact") if layer(module_name(p), "fe_contact") not in FE_LAYERS
             and module_name(p) != "fe_contact"]
    assert not loose, loose


def test_fe_contact_imports_nothing_from_pushplan_mujoco_or_rerun():
    for path in modules("fe_contact"):
        for name in imported_modules(path):
            assert name.split(".")[0] not in ("pushplan", "mujoco", "rerun"), (path, name)


def test_pushplan_uses_fe_contact_through_its_public_face_only():
    """Issue 44: pushplan imports fe_contact's names from ``fe_contact`` itself (its
    ``__init__``), never from a module below it, and every name it takes is in ``__all__``."""
    import fe_contact

    deep, missing = [], []
    for path in modules("pushplan"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and not node.level and (node.module or "").startswith("fe_contact"):
                if node.module != "fe_contact":
                    deep.append(f"{path.relative_to(ROOT)}:{node.lineno} from {node.module}")
                missing += [f"{path.relative_to(ROOT)}: {a.name}" for a in node.names if a.name not in fe_contact.__all__]
            elif isinstance(node, ast.Import):
                deep += [f"{path.relative_to(ROOT)}:{node.lineno} import {a.name}" for a in node.names
                         if a.name.startswith("fe_contact.")]
    assert not deep, "\n".join(deep)
    assert not missing, "\n".join(missing)


@pytest.mark.parametrize("package", ["pushplan", "fe_contact"])
def test_no_import_cycle(package):
    """Imports inside functions count: ``imported_modules`` walks the whole tree."""
    known = {module_name(p): p for p in modules(package)}
    graph = {m: {n for n in imported_modules(p) if n in known and n != m} for m, p in known.items()}
    done, stack = set(), []

    def visit(m):
        if m in stack:
            raise AssertionError("import cycle: " + " -> ".join(stack[stack.index(m):] + [m]))
        if m in done:
            return
        stack.append(m)
        for n in graph[m]:
            if not (m.startswith(n + ".") and n in known):  # a package's submodule importing it
                visit(n)
        stack.pop()
        done.add(m)

    for m in graph:
        visit(m)


@pytest.mark.parametrize("package", ["pushplan", "fe_contact"])
def test_modules_and_functions_are_small(package):
    long = []
    for path in modules(package):
        text = path.read_text()
        if len(text.splitlines()) > MAX_MODULE_LINES:
            long.append(f"{path.relative_to(ROOT)}: {len(text.splitlines())} lines")
        for node in ast.walk(ast.parse(text)):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                n = node.end_lineno - node.lineno + 1
                if n > MAX_FUNCTION_LINES:
                    long.append(f"{path.relative_to(ROOT)}:{node.lineno} {node.name}: {n} lines")
    assert not long, "\n".join(long)


def kernel_sources() -> list[Path]:
    """fe_contact's Cython kernels (issue 32), built at install by setup.py."""
    return sorted((ROOT / "fe_contact").rglob("*.pyx"))


def test_compiled_kernels_follow_the_module_rules_and_are_built():
    """Each ``.pyx`` lives in a layer of fe_contact, imports (``import``, ``cimport``,
    ``from``) nothing of a higher layer nor of pushplan/mujoco/rerun, is <= 500 lines
    with top-level functions <= 60 (``MAX_FUNCTION_LINES``), and its extension module imports from the file
    built beside it, no older than the source (an editable install does not rebuild:
    ``make`` reinstalls when a ``.pyx`` changes)."""
    import importlib
    import importlib.machinery

    assert len(kernel_sources()) == 3  # linalg, fem, contact
    wrong = []
    for path in kernel_sources():
        name = module_name(path)
        own = layer(name, "fe_contact")
        text = path.read_text()
        lines = text.splitlines()
        if own not in FE_LAYERS:
            wrong.append(f"{name}: not in a layer")
        for mod in re.findall(r"^\s*(?:from|c?import)\s+([\w.]+)", text, re.M):
            level = len(mod) - len(mod.lstrip("."))
            package = name.split(".")[:-1]
            absolute = ".".join([*package[:len(package) - level + 1], mod[level:]]) if level else mod
            other = layer(absolute, "fe_contact")
            if mod.split(".")[0] in ("pushplan", "mujoco", "rerun") or (
                    other in FE_LAYERS and FE_LAYERS.index(other) > FE_LAYERS.index(own)):
                wrong.append(f"{name} imports {mod}")
        if len(lines) > MAX_MODULE_LINES:
            wrong.append(f"{name}: {len(lines)} lines")
        starts = [i for i, line in enumerate(lines) if re.match(r"(c?p?def) ", line)]
        for i in starts:
            end = next((j for j in range(i + 1, len(lines)) if lines[j][:1] not in ("", " ", "#")), len(lines))
            while not lines[end - 1].strip():
                end -= 1
            if end - i > MAX_FUNCTION_LINES:
                wrong.append(f"{name}:{i + 1}: {end - i} lines")
        built = importlib.import_module(name).__file__
        if not built.endswith(tuple(importlib.machinery.EXTENSION_SUFFIXES)) or \
                Path(built).stat().st_mtime < path.stat().st_mtime:
            wrong.append(f"{name}: {built} is not built from {path.name} (reinstall: make .venv/.installed)")
    assert not wrong, "\n".join(wrong)


def sources_matching(pattern: str, package="pushplan") -> list[str]:
    regex = re.compile(pattern)
    return sorted(str(p.relative_to(ROOT)) for p in modules(package) if regex.search(p.read_text()))


def test_one_fe_driving_loop():
    # one loop over steps, fe_contact's StepSequence (run and run_release iterate it); in
    # pushplan only the driver steps fe_contact, through it
    steps = r"\bStepSequence\b|fe_contact(\.stepping)?(\.step)? import[^\n]*\b(step|run|run_release)\b|" \
            r"fe_contact\.(step|run|run_release)\("
    assert sources_matching(steps) == ["pushplan/run/driver.py"]
    loops = sources_matching(r"for [^\n]* in [^\n]*\b(_commands|next_command)\(|:= [^\n]*next_command\(",
                             "fe_contact") + sources_matching(r"next_command\(")
    assert loops == ["fe_contact/stepping/sequence.py"]


def test_one_atomic_writer():
    assert sources_matching(r"os\.replace\(|mkstemp|NamedTemporaryFile|os\.umask") == ["pushplan/outputs/atomic.py"]


def test_one_command_codec():
    # a Command written out field by field, or built from an array row, only in the codec
    assert sources_matching(r"[\"']dtheta_deg[\"']\s*:|Command\(dx=float") == ["pushplan/config/commands.py"]


def test_public_names_are_the_exports():
    import fe_contact
    import pushplan

    assert sorted(pushplan.__all__) == sorted(pushplan._EXPORTS)
    assert all(hasattr(fe_contact, n) for n in fe_contact.__all__)


def test_one_orthotropy_frame():
    # fe_contact.local_frame is the one implementation; the FE model, the reduced model,
    # the identification and the recordings use it
    defs = sources_matching(r"def (local_frame|rotation_matrix)\(", "fe_contact") + \
        sources_matching(r"def (local_frame|rotation_matrix)\(")
    assert defs == ["fe_contact/contact/friction.py"]


def readme_map() -> dict[str, str]:
    """The README's architecture map: the text of each folder's section, by folder path."""
    text = (ROOT / "README.md").read_text()
    block = re.search(r"## Architecture.*?```text\n(.*?)```", text, re.S)
    assert block, "README.md has no ```text map under '## Architecture'"
    sections, top, current = {}, "", None
    for line in block.group(1).splitlines():
        m = re.match(r"^( *)(\w+)/", line)
        if m and len(m.group(1)) <= 2:
            top = m.group(2) if not m.group(1) else top
            current = m.group(2) if not m.group(1) else f"{top}/{m.group(2)}"
            sections[current] = line
        elif current is not None:
            sections[current] += "\n" + line
    return sections


def test_readme_map_names_every_fe_contact_module_and_pushplan_room():
    """Issue 44: every module of fe_contact (.py and compiled .pyx) is named in its folder's section
    of the README's map, with its job; every pushplan subpackage (room) has a line."""
    sections = readme_map()
    missing = []
    for path in sorted((ROOT / "fe_contact").rglob("*.py")) + kernel_sources():
        rel = path.relative_to(ROOT / "fe_contact")
        if rel.name == "__init__.py" or len(rel.parts) != 2:
            continue
        name = rel.name if path.suffix == ".pyx" else rel.stem
        if not re.search(rf"(?<![\w.]){re.escape(name)}(?![\w])", sections.get(f"fe_contact/{rel.parts[0]}", "")):
            missing.append(str(rel))
    rooms = [p.name for p in sorted((ROOT / "pushplan").iterdir()) if (p / "__init__.py").exists()]
    missing += [f"pushplan/{room}/" for room in rooms if f"pushplan/{room}" not in sections]
    assert not missing, "not in the README's map: " + ", ".join(missing)
