"""The shared test data lives once, in tests/scenes.py (issue 21): no other test module
defines its own TINY_SPEC, quad, point_light or inside_sphere, and service tests import
shared helpers from scenes / service_harness, never from another test module."""

from __future__ import annotations

import ast
from pathlib import Path

TESTS = Path(__file__).resolve().parent
SHARED = {"TINY_SPEC", "quad", "point_light", "inside_sphere"}
#: Service test modules still importing from other test modules, with who removes it.
#: test_service_supervision.py is another engineer's file in progress (issue 21 item
#: "worker loss"): it should import TINY_SPEC from scenes and single_bundle from
#: service_harness.
IMPORT_EXCEPTIONS = {"test_service_supervision.py"}


def _modules():
    for path in sorted(TESTS.rglob("*.py")):
        if path.name != "scenes.py" and ".venv" not in path.parts:
            yield path, ast.parse(path.read_text(encoding="utf-8"))


def test_shared_data_is_defined_once():
    copies = []
    for path, tree in _modules():
        for node in tree.body:
            names = ([node.name] if isinstance(node, ast.FunctionDef) else
                     [t.id for t in node.targets if isinstance(t, ast.Name)]
                     if isinstance(node, ast.Assign) else [])
            copies += [f"{path.relative_to(TESTS)}:{node.lineno} {n}" for n in names
                       if n in SHARED]
    assert not copies, "defined outside tests/scenes.py: " + ", ".join(copies)


def test_service_tests_do_not_import_test_modules():
    bad = []
    for path, tree in _modules():
        if path.parent.name != "service" or path.name in IMPORT_EXCEPTIONS:
            continue
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("test_"):
                bad.append(f"{path.name}:{node.lineno} from {node.module}")
            if isinstance(node, ast.Import):
                bad += [f"{path.name}:{node.lineno} import {a.name}" for a in node.names
                        if a.name.startswith("test_")]
    assert not bad, "service tests importing test modules: " + ", ".join(bad)
