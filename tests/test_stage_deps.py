"""dvc.yaml is honest about code: every scanloc module a stage's command imports (statically,
function-local imports included, plus the classes its params files name as Hydra `_target_`s)
is one of the stage's deps, or lies in a dep folder. A module missing there could change
without DVC rerunning the stage, and dvc.lock would no longer say what made the outputs."""

from __future__ import annotations

import ast
import re
from functools import cache
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parents[1]
SRC = REPO_ROOT / "src"
TARGET = re.compile(r"_target_:\s*(scanloc\.[\w.]+)")


def module_file(module: str) -> Path | None:
    base = SRC / Path(*module.split("."))
    for path in (base / "__init__.py", base.with_suffix(".py")):
        if path.is_file():
            return path
    return None


@cache
def imported_modules(path: Path) -> frozenset[str]:
    """The scanloc modules `path` imports anywhere in its body."""
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found |= {a.name for a in node.names if a.name.startswith("scanloc")}
        elif isinstance(node, ast.ImportFrom) and (node.module or "").startswith("scanloc"):
            found.add(node.module)
            found |= {
                f"{node.module}.{a.name}"
                for a in node.names
                if module_file(f"{node.module}.{a.name}")
            }
    return frozenset(found)


def closure(modules: set[str]) -> set[Path]:
    """The files of `modules` and of everything they import, transitively."""
    seen: set[str] = set()
    todo = list(modules)
    while todo:
        module = todo.pop()
        if module in seen or (path := module_file(module)) is None:
            continue
        seen.add(module)
        todo += [".".join(module.split(".")[:i]) for i in range(1, module.count(".") + 1)]
        todo += imported_modules(path)
    return {p for m in seen if (p := module_file(m)) is not None}


def stages() -> list[tuple[str, str, list[str], list[str]]]:
    """(name, cmd, dep paths, params files) of every stage, foreach/matrix expanded."""
    from dvc.repo import Repo

    repo = Repo(str(REPO_ROOT))
    out = []
    for stage in repo.index.stages:
        deps = [
            str(Path(d.def_path))
            for d in stage.deps
            if not d.__class__.__name__.startswith("Param")
        ]
        params = [
            str(Path(d.def_path)) for d in stage.deps if d.__class__.__name__.startswith("Param")
        ]
        out.append((stage.addressing, stage.cmd, deps, params))
    return out


def test_init_files_hold_no_code() -> None:
    """Package __init__ files are exempt below: they must hold only a docstring and constants
    (scanloc's __version__), never code a stage runs."""
    for path in SRC.rglob("__init__.py"):
        for node in ast.parse(path.read_text()).body:
            assert isinstance(node, (ast.Expr, ast.Assign)), path
            assert isinstance(node.value, ast.Constant), path


@pytest.mark.parametrize("stage", stages(), ids=lambda s: s[0])
def test_stage_deps_cover_the_code_it_runs(stage: tuple[str, str, list[str], list[str]]) -> None:
    name, cmd, deps, params = stage
    entry = re.search(r"python -m (scanloc\.[\w.]+)", cmd)
    assert entry, f"{name}: expected `python -m scanloc.<module>` in its cmd"
    modules = {entry.group(1)}
    for params_file in params:
        path = REPO_ROOT / params_file
        if path.suffix == ".yaml" and path.is_file():
            modules |= {t.rsplit(".", 1)[0] for t in TARGET.findall(path.read_text())}
    covered = [REPO_ROOT / d for d in deps]
    missing = sorted(
        str(f.relative_to(REPO_ROOT))
        for f in closure(modules)
        if f.name != "__init__.py" and not any(f == c or c in f.parents for c in covered)
    )
    assert not missing, f"dvc.yaml stage {name}: add to its deps: {missing}"
