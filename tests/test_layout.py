"""The rooms of docs/ARCHITECTURE.md and what each may import.

Read from the source (ast), so a forbidden import fails here even on a code path no other
test runs; and from a fresh interpreter, so the math library's "no I/O" is what Python
actually loads.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

# room -> the other rooms it may import (docs/ARCHITECTURE.md, "Who imports whom").
ALLOWED: dict[str, set[str]] = {
    "tvd": set(),
    "protocol": set(),
    "runtime": {"protocol"},
    "world": {"tvd", "protocol"},
    "mission": {"tvd", "world"},
    "records": {"tvd", "protocol", "runtime", "mission", "world"},
    "agent": {"tvd", "protocol", "runtime", "world"},
    "sim_robot": {"tvd", "protocol", "runtime", "world"},
    "bridge": {"tvd", "protocol", "runtime", "mission"},
    "coordinator": {"tvd", "protocol", "runtime", "mission", "records", "world"},
    "console": {"tvd", "protocol", "runtime", "coordinator", "world"},
    "deploy": {
        "tvd", "protocol", "runtime", "mission", "records", "agent", "sim_robot", "bridge",
        "coordinator", "console", "world",
    },
}  # fmt: skip
LEGACY = {"agent", "protocol", "coordinator", "sim_robot", "deploy", "tvd", "mission"}


def imported_modules(path: Path) -> list[str]:
    modules = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            modules.append(node.module)
            modules += [f"{node.module}.{alias.name}" for alias in node.names]
        elif isinstance(node, ast.Import):
            modules += [alias.name for alias in node.names]
    return modules


def test_every_package_is_a_room_with_rules() -> None:
    packages = {p.parent.name for p in ROOT.glob("*/__init__.py")}
    assert packages == set(ALLOWED), "a new top-level package needs its rules here and a room"
    mapped = (ROOT / "pyproject.toml").read_text(encoding="utf-8")
    for room in ALLOWED:
        assert f'"covswarm.{room}" = "{room}"' in mapped, f"{room} not installed as covswarm"


@pytest.mark.parametrize("room", sorted(ALLOWED))
def test_rooms_import_only_what_they_may(room: str) -> None:
    bad = []
    for path in sorted((ROOT / room).rglob("*.py")):
        for module in imported_modules(path):
            top, _, rest = module.partition(".")
            if top in LEGACY:
                bad.append(f"{path.relative_to(ROOT)}: '{module}' (import covswarm.{module})")
            elif top == "covswarm" and rest:
                other = rest.split(".")[0]
                if other != room and other not in ALLOWED[room]:
                    bad.append(f"{path.relative_to(ROOT)}: {module}")
    assert not bad, "\n".join(bad)


def test_the_rules_have_no_cycle() -> None:
    seen: dict[str, int] = {}

    def visit(room: str) -> None:
        if seen.get(room) == 1:
            raise AssertionError(f"import cycle through {room}")
        if seen.get(room) == 2:
            return
        seen[room] = 1
        for other in ALLOWED[room]:
            visit(other)
        seen[room] = 2

    for room in ALLOWED:
        visit(room)


def module_name(path: Path) -> str:
    """covswarm's dotted name of the module at ``path`` (a package is its __init__)."""
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(("covswarm", *(parts[:-1] if parts[-1] == "__init__" else parts)))


def test_no_import_cycle_inside_a_room() -> None:
    """No module of a room reaches itself through imports of the same room, counting the
    imports inside functions and under TYPE_CHECKING too: a cycle hidden in a function
    still ties the two modules into one concept, and breaks the day the import moves up."""
    modules = {module_name(p): p for room in ALLOWED for p in (ROOT / room).rglob("*.py")}
    edges = {
        name: {
            other
            for other in imported_modules(path)
            if other in modules and other != name and other.split(".")[1] == name.split(".")[1]
        }
        for name, path in modules.items()
    }
    state: dict[str, int] = {}  # 1: on the current path, 2: done
    path: list[str] = []

    def visit(name: str) -> None:
        state[name] = 1
        path.append(name)
        for other in sorted(edges[name]):
            if state.get(other) == 1:
                cycle = path[path.index(other) :] + [other]
                raise AssertionError("import cycle: " + " -> ".join(cycle))
            if other not in state:
                visit(other)
        path.pop()
        state[name] = 2

    for name in sorted(modules):
        if name not in state:
            visit(name)


IO_LIBRARIES = ("zenoh", "click", "matplotlib")  # what a sans-IO module must not load


def assert_loads_none(modules: str, forbidden: tuple[str, ...]) -> None:
    """Importing ``modules`` (comma-separated) in a fresh interpreter loads none of
    ``forbidden``."""
    code = (
        "import sys\n"
        f"import {modules}\n"
        f"bad = [m for m in {forbidden!r} if m in sys.modules]\n"
        "assert not bad, bad\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


def test_math_library_loads_no_io() -> None:
    assert_loads_none(
        "covswarm.tvd.coverage, covswarm.tvd.control, covswarm.tvd.density, "
        "covswarm.tvd.drive, covswarm.tvd.safety",
        (*IO_LIBRARIES, "msgpack", "aiohttp", "rich", "foxglove", "mcap", "covswarm.protocol"),
    )


def test_agent_brain_is_sans_io() -> None:
    assert_loads_none("covswarm.agent.brain", IO_LIBRARIES)


def test_coordinator_core_is_sans_io() -> None:
    assert_loads_none("covswarm.coordinator.core", IO_LIBRARIES)
