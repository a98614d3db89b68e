"""The type stubs name what the native module has, and the docstrings
are there for an editor to show."""

import ast
import inspect
from pathlib import Path

import cqnet
from cqnet import _cqnet


def stub_names():
    stub = Path(cqnet.__file__).with_name("_cqnet.pyi")
    tree = ast.parse(stub.read_text())
    top, members = set(), {}
    for node in tree.body:
        if isinstance(node, (ast.FunctionDef, ast.ClassDef)):
            top.add(node.name)
        if isinstance(node, ast.ClassDef):
            members[node.name] = {
                n.name for n in node.body if isinstance(n, ast.FunctionDef) and not n.name.startswith("_")
            }
        if isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
            top.add(node.target.id)
    return top, members


def test_the_stub_names_every_public_name_of_the_native_module_and_no_other():
    top, members = stub_names()
    public = {n for n in dir(_cqnet) if not n.startswith("_")} | {"__version__"}
    assert top - {"_Path", "_Floats"} == public
    for name, methods in members.items():
        native = {
            n for n, v in vars(getattr(_cqnet, name)).items()
            if not n.startswith("_")
        }
        assert methods == native, name


def test_every_public_function_and_class_has_a_docstring():
    for name in dir(_cqnet):
        if name.startswith("_"):
            continue
        thing = getattr(_cqnet, name)
        if callable(thing):
            assert inspect.getdoc(thing), name


def test_mypy_stubtest_finds_the_stub_true_to_the_module():
    """mypy's stubtest compares every signature, default and class of the
    stub with the module as built."""
    import subprocess
    import sys

    import pytest

    pytest.importorskip("mypy")
    allowlist = Path(__file__).with_name("stubtest-allowlist.txt")
    done = subprocess.run(
        [sys.executable, "-m", "mypy.stubtest", "cqnet._cqnet", "--allowlist", str(allowlist)],
        capture_output=True,
        text=True,
        cwd=Path(__file__).parent,
    )
    assert done.returncode == 0, done.stdout + done.stderr
