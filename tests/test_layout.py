"""The package layout (docs: README's layout table): stages import only stages below them,
Mitsuba only in the scene kernel, imc's top level small. Reads the imports with ast."""

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: each stage and what it may import of imcsim (the data flow, top to bottom)
ALLOWED = {
    "orbit": {"orbit"},
    "camera": {"camera", "orbit"},
    "scene": {"scene", "camera", "orbit"},
    "correlator": {"correlator"},
    "compensation": {"compensation"},
    "ground": {"ground", "compensation"},
    "imc": {"imc", "orbit", "scene", "camera", "correlator", "compensation", "ground"},
}
PACKAGES = set(ALLOWED)


def _imports(path: Path) -> set[str]:
    tree = ast.parse(path.read_text())
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module.split(".")[0])
    return names


@pytest.mark.parametrize("stage", sorted(ALLOWED))
def test_a_stage_imports_no_higher_stage(stage):
    for f in (ROOT / stage).rglob("*.py"):
        bad = (_imports(f) & PACKAGES) - ALLOWED[stage]
        assert not bad, f"{f.relative_to(ROOT)} imports {sorted(bad)}"


def test_mitsuba_only_in_the_scene_kernel():
    for pkg in PACKAGES:
        for f in (ROOT / pkg).rglob("*.py") if (ROOT / pkg).is_dir() else ():
            if f.relative_to(ROOT).as_posix() != "scene/kernel.py":
                assert not _imports(f) & {"mitsuba", "drjit"}, f.relative_to(ROOT)


def test_imc_top_level_is_small_and_sub_packages_say_what_they_own():
    assert len(list((ROOT / "imc").glob("*.py"))) <= 8
    for init in (ROOT / "imc").glob("*/__init__.py"):
        assert ast.get_docstring(ast.parse(init.read_text())), init


def _package_dirs() -> list[Path]:
    return sorted(p.parent for pkg in PACKAGES for p in (ROOT / pkg).rglob("__init__.py"))


@pytest.mark.parametrize("package", _package_dirs(), ids=lambda p: p.relative_to(ROOT).as_posix())
def test_a_package_docstring_names_every_public_module(package):
    doc = ast.get_docstring(ast.parse((package / "__init__.py").read_text())) or ""
    dotted = package.relative_to(ROOT).as_posix().replace("/", ".")
    for f in sorted(package.glob("*.py")):
        name = f.stem
        if name.startswith("_"):
            continue
        named = (f"`{name}`" in doc or f"`{name}.py`" in doc or f"`{dotted}.{name}`" in doc
                 or f":mod:`{dotted}.{name}`" in doc or f"``{dotted}.{name}``" in doc
                 or f"``{name}``" in doc or f":mod:`.{name}`" in doc)
        assert named, f"{dotted}'s docstring does not name its module {name}"
