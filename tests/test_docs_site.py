"""The front door: the documentation site builds strictly, the README stays short and its
links resolve, the install commands use the lock, CITATION.cff has valid CFF 1.2 keys.

``mkdocs build --strict`` fails on a broken link or anchor, a page missing from the
navigation and an API reference that cannot be collected (mkdocs.yml's ``validation``), so
this file is what makes a broken page fail the README's test command (and CI)."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import yaml

if sys.version_info >= (3, 11):
    import tomllib
else:  # Python 3.10
    import tomli as tomllib

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text(encoding="utf-8")
TEST_COMMAND = (
    "python3 -m venv .venv && .venv/bin/pip install -c constraints.txt -e '.[test]' "
    "&& .venv/bin/python -m pytest -q"
)


def test_the_site_builds_strictly(tmp_path: Path) -> None:
    done = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "-d", str(tmp_path / "site")],
        cwd=ROOT, capture_output=True, text=True, timeout=300,
        env={"NO_MKDOCS_2_WARNING": "1", "PATH": str(Path(sys.executable).parent)},
    )  # fmt: skip
    assert done.returncode == 0, done.stdout + done.stderr
    api = (tmp_path / "site" / "api" / "index.html").read_text(encoding="utf-8")
    for name in ("aggregate_error", "tvd_da", "SteeringClient", "WheelCommand"):
        assert name in api, f"the API reference lost {name}"


def test_the_readme_is_short_and_its_links_resolve() -> None:
    assert len(README.splitlines()) <= 250
    targets = re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", README)
    local = [t for t in targets if "://" not in t]
    assert local, "no local links found: the pattern is wrong"
    missing = [t for t in local if not (ROOT / t).exists()]
    assert not missing, missing
    anchors = re.findall(r"\]\(#([^)]+)\)", README)
    headings = {
        re.sub(r"[^a-z0-9 -]", "", h.lower()).replace(" ", "-")
        for h in re.findall(r"^#+ (.+)$", README, flags=re.MULTILINE)
    }
    assert set(anchors) <= headings, set(anchors) - headings
    # and the anchors of its links into the documentation (as Python-Markdown's toc makes them)
    into = re.findall(r"\]\(([^)#\s]+\.md)#([^)]+)\)", README)
    assert into, "no link into a page's section found: the pattern is wrong"
    for page, anchor in into:
        text = (ROOT / page).read_text(encoding="utf-8")
        slugs = {
            re.sub(r"[-\s]+", "-", re.sub(r"[^\w\s-]", "", h).strip().lower())
            for h in re.findall(r"^#+ (.+)$", text, flags=re.MULTILINE)
        }
        assert anchor in slugs, f"{page}#{anchor}"


def test_installs_come_from_the_lock_and_ci_runs_the_readmes_command() -> None:
    collapsed = " ".join(README.split())
    assert TEST_COMMAND in collapsed
    assert "pip install -c constraints.txt -e . && .venv/bin/covswarm run" in collapsed
    ci = (ROOT / ".ci" / "run").read_text(encoding="utf-8").strip().splitlines()
    assert ci[-1] == TEST_COMMAND, "the last line of .ci/run is the README's test command"


def requirement_names(requirements: list[str]) -> set[str]:
    """Normalised project names of PEP 508 requirement strings."""
    names = {re.split(r"[\s<>=!~;\[(]", r, maxsplit=1)[0] for r in requirements}
    return {re.sub(r"[-_.]+", "-", n).lower() for n in names}


def test_the_lock_pins_every_dependency() -> None:
    """constraints.txt (uv pip compile, all extras) pins every requirement of pyproject."""
    project = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]
    wanted = requirement_names(project["dependencies"])
    for extra in project["optional-dependencies"].values():
        wanted |= requirement_names([r for r in extra if not r.startswith("covswarm")])
    lines = (ROOT / "constraints.txt").read_text(encoding="utf-8").splitlines()
    pinned = requirement_names([line for line in lines if "==" in line])
    assert wanted <= pinned, f"refresh constraints.txt (docs/development.md): {wanted - pinned}"
    assert {"pyyaml", "pillow", "mkdocs", "build"} <= pinned


# The keys of the Citation File Format 1.2.0 schema (schema.json of citation-file-format),
# top level and those of a reference (preferred-citation, references[]).
CFF_KEYS = {
    "abstract", "authors", "cff-version", "commit", "contact", "date-released", "doi",
    "identifiers", "keywords", "license", "license-url", "message", "preferred-citation",
    "references", "repository", "repository-artifact", "repository-code", "title", "type",
    "url", "version",
}  # fmt: skip
REFERENCE_REQUIRED = {"type", "title", "authors"}
PERSON_KEYS = {
    "address", "affiliation", "alias", "city", "country", "email", "family-names", "fax",
    "given-names", "name-particle", "name-suffix", "orcid", "post-code", "region", "tel",
    "website", "name", "date-end", "date-start", "location",
}  # fmt: skip


def test_citation_cff_has_valid_cff_1_2_keys() -> None:
    cff = yaml.safe_load((ROOT / "CITATION.cff").read_text(encoding="utf-8"))
    assert {"cff-version", "message", "title", "authors"} <= set(cff)
    assert set(cff) <= CFF_KEYS, set(cff) - CFF_KEYS
    assert cff["cff-version"] == "1.2.0" and cff["type"] in ("software", "dataset")
    paper = [cff["preferred-citation"], *cff["references"]]
    for reference in paper:
        assert REFERENCE_REQUIRED <= set(reference)
        assert reference["title"] == "Multi-Agent Control Using Coverage Over Time-Varying Domains"
        assert [a["family-names"] for a in reference["authors"]] == ["Xu", "Diaz-Mercado"]
    for person in [a for r in [cff, *paper] for a in r["authors"]]:
        assert person and set(person) <= PERSON_KEYS, person
    version = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["version"]
    assert str(cff["version"]) == version
