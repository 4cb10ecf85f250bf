"""covswarm as a package: ``python -m build`` makes an sdist and a wheel (the wheel built from
the sdist, so the sdist is complete), each installs into a fresh venv and runs a short
``covswarm sim --scenario passage`` there, with the console's static assets inside.

No download: the build runs without isolation (setuptools and build come with the test
extra), the fresh venv sees the current venv's dependencies through a path file, and
covswarm itself is installed with ``--no-deps --no-index``. The current venv's editable
install is not on the fresh venv's path (a path entry does not run that venv's .pth files),
so what runs is the installed package.
"""

from __future__ import annotations

import json
import site
import subprocess
import sys
import tarfile
import venv
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
ASSETS = ("index.html", "console.js", "console.css")
WHERE = """
import json, importlib.metadata, importlib.resources
import covswarm.console, covswarm.tvd
static = importlib.resources.files("covswarm.console") / "static"
print(json.dumps({
    "tvd": covswarm.tvd.__file__,
    "static": sorted(p.name for p in static.iterdir()),
    "version": importlib.metadata.version("covswarm"),
}))
"""


@pytest.fixture(scope="module")
def dist(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("dist")
    done = subprocess.run(
        [sys.executable, "-m", "build", "--no-isolation", "--outdir", str(out), str(ROOT)],
        capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    return out


def version() -> str:
    done = subprocess.run(
        [sys.executable, "-c", "import importlib.metadata as m; print(m.version('covswarm'))"],
        capture_output=True, text=True, check=True,
    )  # fmt: skip
    return done.stdout.strip()


def test_the_sdist_and_the_wheel_carry_the_console_assets(dist: Path) -> None:
    (sdist,) = dist.glob("covswarm-*.tar.gz")
    (wheel,) = dist.glob("covswarm-*.whl")
    with tarfile.open(sdist) as tar:
        names = tar.getnames()
    for asset in ASSETS:
        assert any(n.endswith(f"console/static/{asset}") for n in names), asset
    assert any(n.endswith("/LICENSE") for n in names)
    with zipfile.ZipFile(wheel) as whl:
        names = whl.namelist()
    for asset in ASSETS:
        assert f"covswarm/console/static/{asset}" in names, asset
    assert {n.split("/")[1] for n in names if n.startswith("covswarm/")} >= {
        "tvd", "protocol", "agent", "coordinator", "deploy", "console", "records", "mission",
    }  # fmt: skip


@pytest.mark.e2e
@pytest.mark.parametrize("kind", ["whl", "tar.gz"])
def test_installs_into_a_fresh_venv_and_simulates(kind: str, dist: Path, tmp_path: Path) -> None:
    (package,) = dist.glob(f"covswarm-*.{kind}")
    env_dir = tmp_path / "venv"
    venv.create(env_dir, with_pip=False)
    python = env_dir / "bin" / "python"
    purelib = subprocess.run(
        [str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
        capture_output=True, text=True, check=True,
    ).stdout.strip()  # fmt: skip
    # the dependencies from this venv (no download); appended after the fresh site-packages
    (Path(purelib) / "covswarm-test-deps.pth").write_text("\n".join(site.getsitepackages()))
    install = [sys.executable, "-m", "pip", "--python", str(python), "install", "-q"]
    done = subprocess.run(
        [*install, "--no-deps", "--no-index", "--no-build-isolation", str(package)],
        capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert done.returncode == 0, done.stdout + done.stderr
    work = tmp_path / "work"  # not the repository: nothing imports from the clone
    work.mkdir()
    where = subprocess.run(
        [str(python), "-c", WHERE], cwd=work, capture_output=True, text=True, timeout=120
    )
    assert where.returncode == 0, where.stderr
    found = json.loads(where.stdout)
    assert found["tvd"].startswith(purelib), found  # the installed copy, not the clone
    assert set(ASSETS) <= set(found["static"]) and found["version"] == version()
    covswarm = env_dir / "bin" / "covswarm"
    said = subprocess.run(
        [str(covswarm), "--version"], cwd=work, capture_output=True, text=True, timeout=120
    )
    assert said.returncode == 0 and version() in said.stdout, said.stdout + said.stderr
    run = subprocess.run(
        [str(covswarm), "sim", "--scenario", "passage", "--agents", "4", "--duration", "2",
         "--dt", "0.05", "--out", "runs/passage"],
        cwd=work, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert run.returncode == 0, run.stdout[-2000:] + run.stderr[-2000:]
    summary = json.loads((work / "runs" / "passage" / "summary.json").read_text())
    assert summary["scenario"] == "passage" and summary["agents"] == 4
    assert (work / "runs" / "passage" / "run.mcap").stat().st_size > 0
