"""The bake service's layering, read from the source (every import, function-level ones
included): ``jobs`` is the bottom layer; ``service`` (API) and ``workers`` both sit on it and
never import each other; all three use the library only through ``prtcore``'s public
names; the library imports none of them (``serve``/``worker`` reach the CLI through the
``prtcore.commands`` entry-point group)."""

from __future__ import annotations

import ast
from importlib.metadata import entry_points

import pytest
from service_harness import ROOT

APPS = ("jobs", "service", "workers")
#: package → top-level packages of this repository it must not import
FORBIDDEN = {"jobs": {"service", "workers"}, "service": {"workers"},
             "workers": {"service"}, "prtcore": set(APPS)}


def imports(package: str) -> list[tuple[str, int, str, list[str]]]:
    """(file, line, absolute module, imported names) for every import under ``package``."""
    out = []
    for path in sorted((ROOT / package).rglob("*.py")):
        rel = path.relative_to(ROOT)
        parts = list(rel.with_suffix("").parts)
        pkg = parts[:-1]  # the package a relative import starts from
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Import):
                out += [(str(rel), node.lineno, a.name, []) for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    base = pkg[:len(pkg) - node.level + 1]
                    mod = ".".join(base + ([node.module] if node.module else []))
                else:
                    mod = node.module or ""
                out.append((str(rel), node.lineno, mod, [a.name for a in node.names]))
    return out


@pytest.mark.parametrize("package", sorted(FORBIDDEN))
def test_layers_import_downward_only(package):
    bad = [f"{f}:{n}: {m}" for f, n, m, _ in imports(package)
           if m.split(".")[0] in FORBIDDEN[package]]
    assert not bad, f"{package} must not import {sorted(FORBIDDEN[package])}: {bad}"


@pytest.mark.parametrize("package", APPS)
def test_apps_use_only_the_public_names_of_prtcore(package):
    import prtcore

    bad = []
    for f, n, mod, names in imports(package):
        if mod.startswith("prtcore."):
            bad.append(f"{f}:{n}: {mod}")
        elif mod == "prtcore":
            bad += [f"{f}:{n}: prtcore.{x}" for x in names if x not in prtcore.__all__]
    assert not bad, f"private prtcore imports: {bad}"


def test_serve_and_worker_are_entry_point_commands():
    eps = {ep.name: ep.value for ep in entry_points(group="prtcore.commands")}
    assert eps.get("serve") == "service.cli:register"
    assert eps.get("worker") == "workers.cli:register"
    from prtcore.cli import build_parser

    p = build_parser()
    args = p.parse_args(["serve", "--port", "9", "--workers", "2", "--api-workers", "3"])
    assert (args.host, args.port, args.workers, args.api_workers) == ("127.0.0.1", 9, 2, 3)
    assert callable(args.func)
    args = p.parse_args(["worker", "--concurrency", "4"])
    assert args.concurrency == 4 and callable(args.func)
