"""Claims the README makes about the code itself, and the test suite's own rules.

- "`ruff check` and `ruff format` are clean": both run here, on the whole repository.
- "multicast scouting and gossip are off everywhere": every Zenoh configuration covswarm
  opens comes from protocol.session.session_config (no other module builds a zenoh.Config),
  and that one has both off in every mode, secured or not.
- Test modules never import each other (shared code lives in tests/conftest.py and in
  helper modules whose names do not start with ``test_``).
- Every test that opens a Zenoh session or starts swarm processes is marked ``e2e`` (so
  ``pytest -m "not e2e"`` leaves them all out).
- The README's and docs' Python examples parse, and everything they import exists.
- ``pytest -q`` as a user who is not root skips the multi-host test with its reason, and
  fails it under CI=true (tests/conftest.py ``require``).
- The suite's two workers keep the end-to-end tests on one of them, one at a time, and each
  other module on one worker (docs/development.md).
"""

from __future__ import annotations

import ast
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from covswarm import protocol
from covswarm.protocol.session import MODES

ROOT = Path(__file__).resolve().parents[1]
TESTS = ROOT / "tests"


def package_folders() -> list[Path]:
    """The folders installed as covswarm.<name> (pyproject's package-dir)."""
    return sorted(p.parent for p in ROOT.glob("*/__init__.py"))


@pytest.mark.parametrize("command", [["check"], ["format", "--check"]], ids=" ".join)
def test_ruff_is_clean(command: list[str], require) -> None:
    ruff = Path(sys.executable).with_name("ruff")
    require(ruff.exists(), "needs ruff (pip install -e '.[test]')")
    done = subprocess.run(
        [str(ruff), *command, "."], cwd=ROOT, capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stdout + done.stderr


@pytest.mark.parametrize("mode", MODES)
def test_multicast_scouting_and_gossip_are_off_in_every_mode(mode: str, tmp_path: Path) -> None:
    endpoints = ["tcp/127.0.0.1:7447"]
    config = protocol.session_config(endpoints, endpoints if mode != "client" else None, mode)
    for key in ("scouting/multicast/enabled", "scouting/gossip/enabled"):
        assert config.get_json(key) == "false", (mode, key, config.get_json(key))


def test_secured_sessions_keep_scouting_and_gossip_off(tmp_path: Path) -> None:
    from covswarm.protocol.security import make_test_credentials

    secure = make_test_credentials(tmp_path / "secure")
    for mode, connect, listen in (("client", True, False), ("router", False, True)):
        endpoints = ["tls/127.0.0.1:7447"]
        config = protocol.session_config(
            endpoints if connect else None, endpoints if listen else None, mode, secure=secure
        )
        assert config.get_json("scouting/multicast/enabled") == "false"
        assert config.get_json("scouting/gossip/enabled") == "false"


CONFIG_MAKERS = {"zenoh.Config", "zenoh.Config.from_file", "zenoh.Config.from_json5"}


def test_only_session_config_builds_a_zenoh_config() -> None:
    """A zenoh.Config made anywhere else could leave scouting or gossip on."""
    home = ROOT / "protocol" / "session.py"
    found = []
    for folder in package_folders():
        for path in sorted(folder.rglob("*.py")):
            if path == home:
                continue
            for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
                if isinstance(node, ast.Call) and ast.unparse(node.func) in CONFIG_MAKERS:
                    found.append(f"{path.relative_to(ROOT)}:{node.lineno}")
    assert not found, found


def test_test_modules_do_not_import_each_other() -> None:
    modules = {p.stem for p in TESTS.glob("test_*.py")}
    found = []
    for path in sorted(TESTS.glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            names = []
            if isinstance(node, ast.Import):
                names = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module:
                names = [node.module]
            found += [f"{path.name} imports {n}" for n in names if n.split(".")[0] in modules]
    assert not found, found


# What starts a router, a session or swarm processes, in a test's body or in a fixture or
# helper of its module that it uses (one-shot ``python -c`` import checks do not count).
STARTS = ("zenoh.open(", "Popen(", "launch(", "*covswarm_argv()", "ROUTER", '"run", "--')


def unmarked_e2e_tests(path: Path) -> list[str]:
    source = path.read_text(encoding="utf-8")
    tree = ast.parse(source)
    if "pytestmark = pytest.mark.e2e" in source:
        return []
    functions = {n.name: n for n in tree.body if isinstance(n, ast.FunctionDef | ast.ClassDef)}

    def starts(node: ast.AST, seen: set[str]) -> bool:
        text = ast.get_source_segment(source, node) or ""
        if any(word in text for word in STARTS):
            return True
        used = {n.id for n in ast.walk(node) if isinstance(n, ast.Name)}
        if isinstance(node, ast.FunctionDef):
            used |= {a.arg for a in node.args.args}
        return any(
            starts(functions[name], seen | {name})
            for name in used & set(functions) - seen - {getattr(node, "name", "")}
        )

    unmarked = []
    for node in tree.body:
        if isinstance(node, ast.FunctionDef) and node.name.startswith("test_"):
            marks = " ".join(ast.unparse(d) for d in node.decorator_list)
            if "e2e" not in marks and starts(node, {node.name}):
                unmarked.append(f"{path.name}::{node.name}")
    return unmarked


def test_tests_that_start_processes_are_marked_e2e() -> None:
    found = [name for path in sorted(TESTS.glob("test_*.py")) for name in unmarked_e2e_tests(path)]
    assert not found, found


def python_examples() -> list[tuple[str, str]]:
    """(where, code) of every fenced python block in README.md and docs/*.md."""
    examples = []
    for path in [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]:
        blocks = path.read_text(encoding="utf-8").split("```python\n")[1:]
        examples += [(f"{path.name}#{k}", block.split("```")[0]) for k, block in enumerate(blocks)]
    return examples


def test_documented_python_examples_parse_and_their_imports_exist() -> None:
    examples = python_examples()
    assert examples, "the README's bridge example is gone"
    for where, code in examples:
        tree = ast.parse(code, filename=where)  # a syntax error fails here
        imports = [n for n in tree.body if isinstance(n, ast.Import | ast.ImportFrom)]
        script = "\n".join(ast.unparse(node) for node in imports)
        done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
        assert done.returncode == 0, f"{where}: {done.stderr}"


PRETEND_NOT_ROOT = """
import os, sys, pytest
os.geteuid = lambda: 1000  # as a contributor who is not root sees it
sys.exit(pytest.main(["-q", "-rs", "-p", "no:cacheprovider", "-n", "0", sys.argv[1]]))
"""


@pytest.mark.parametrize("ci", [False, True], ids=["contributor", "ci"])
def test_the_multihost_test_skips_for_non_root_and_fails_in_ci(ci: bool) -> None:
    env = {k: v for k, v in os.environ.items() if k != "CI"} | ({"CI": "true"} if ci else {})
    done = subprocess.run(
        [sys.executable, "-c", PRETEND_NOT_ROOT, str(TESTS / "test_multihost.py")],
        cwd=ROOT, env=env, capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    if ci:
        assert done.returncode == 1 and "1 failed" in done.stdout, done.stdout
    else:
        assert done.returncode == 0 and "1 skipped" in done.stdout, done.stdout
        assert "needs root" in done.stdout


GROUPED_MODULE = """
import os, pathlib, pytest

def record(name):
    pathlib.Path(__file__).with_name(name).write_text(os.environ["PYTEST_XDIST_WORKER"])

@pytest.mark.e2e
@pytest.mark.parametrize("k", range(4))
def test_live(k):
    record(f"{MODULE}-live-{k}")

@pytest.mark.parametrize("k", range(4))
def test_unit(k):
    record(f"{MODULE}-unit-{k}")
"""


def test_end_to_end_tests_share_one_worker_and_each_module_stays_on_one(tmp_path: Path) -> None:
    """tests/conftest.py's groups as pytest-xdist carries them out with the installed pytest
    and pyproject's addopts (on pytest 9.2 it silently drops them: each test alone)."""
    pyproject = (ROOT / "pyproject.toml").read_text(encoding="utf-8")
    addopts = re.search(r'^addopts = "(.*)"$', pyproject, re.MULTILINE)
    assert addopts is not None
    (tmp_path / "conftest.py").write_text((TESTS / "conftest.py").read_text(encoding="utf-8"))
    for module in ("a", "b"):
        (tmp_path / f"test_{module}.py").write_text(f"MODULE = {module!r}\n{GROUPED_MODULE}")
    done = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", *addopts[1].split(),
         "-o", "markers=e2e: live", str(tmp_path)],
        cwd=tmp_path, capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert done.returncode == 0, done.stdout + done.stderr

    def workers(pattern: str) -> list[str]:
        return [path.read_text() for path in tmp_path.glob(pattern)]

    assert len(workers("*-live-*")) == 8 and len(set(workers("*-live-*"))) == 1
    assert len(set(workers("a-unit-*"))) == 1 and len(set(workers("b-unit-*"))) == 1
    assert len(set(workers("*-*-*"))) == 2  # and both workers did work
