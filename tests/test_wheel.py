"""The wheel is what a user installs: built from the repository, it holds the one top-level
package `stepzoo` and the data the commands read, not the development-only benchmarks; in a
fresh venv, from another folder, `stepzoo methods`, the README's Python API example and
(end-to-end, make test-e2e) `stepzoo run` work. Offline: the dependencies come from this venv through a .pth."""
import re
import shutil
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import pytest
from helpers import TINY_SWEEP

ROOT = Path(__file__).resolve().parents[1]
DATA = ["stepzoo/bench/configs/envelope.toml", "stepzoo/bench/configs/small.toml",
        "stepzoo/dynamics/vehicles.toml", "stepzoo/search/planner/tuned_default.toml",
        "stepzoo/search/world/scenarios/street.toml", "stepzoo/search/world/mapdata/PROVENANCE.md",
        "stepzoo/search/world/mapdata/Berlin_1_256.map"]
SKIP = shutil.ignore_patterns(".venv", ".git", "results", "__pycache__", "build", "*.egg-info",
                              ".pytest_cache", ".benchmarks")


@pytest.fixture(scope="module")
def wheel(tmp_path_factory):
    """The wheel, built from a copy of the tree (a build writes build/ and egg-info)."""
    base = tmp_path_factory.mktemp("wheel")
    shutil.copytree(ROOT, base / "src", ignore=SKIP)
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation",
                    "--no-index", "-q", "-w", str(base / "dist"), str(base / "src")],
                   check=True, capture_output=True, timeout=300)
    return next((base / "dist").glob("stepzoo-*.whl"))


@pytest.fixture(scope="module")
def venv(wheel, tmp_path_factory):
    """A fresh venv with the wheel installed, offline; returns its bin folder."""
    env = tmp_path_factory.mktemp("venv") / "env"
    subprocess.run([sys.executable, "-m", "venv", str(env)], check=True, timeout=300)
    python = env / "bin" / "python"
    site = subprocess.run([python, "-c", "import sysconfig; print(sysconfig.get_paths()"
                           "['purelib'])"], capture_output=True, text=True, check=True).stdout
    (Path(site.strip()) / "dev_dependencies.pth").write_text(sysconfig.get_paths()["purelib"])
    subprocess.run([python, "-m", "pip", "install", "--no-deps", "--no-index", "-q",
                    str(wheel)], check=True, capture_output=True, timeout=300)
    return env / "bin"


def test_the_wheel_holds_stepzoo_only_with_its_data_and_without_the_benchmarks(wheel):
    names = zipfile.ZipFile(wheel).namelist()
    top = next(n for n in names if n.endswith("top_level.txt"))
    assert zipfile.ZipFile(wheel).read(top).decode().split() == ["stepzoo"]
    assert {n.split("/")[0] for n in names} == {"stepzoo", top.split("/")[0]}
    assert not [n for n in names if "/perf/" in n]
    assert set(DATA) <= set(names)


def test_stepzoo_methods_runs_from_another_folder(venv, tmp_path):
    proc = subprocess.run([venv / "stepzoo", "methods", "--format", "json"], cwd=tmp_path,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert '"rk4"' in proc.stdout and '"bdf2"' in proc.stdout


def test_the_readme_python_example_prints_what_the_readme_says(venv, tmp_path):
    readme = (ROOT / "README.md").read_text()
    section = readme.split("## Python API", 1)[1]
    code = re.search(r"```python\n(.*?)```", section, re.S).group(1)
    said = re.search(r"prints `(.*?)` and `(.*?)`", section)
    proc = subprocess.run([venv / "python", "-c", code], cwd=tmp_path, capture_output=True,
                          text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    first, second = proc.stdout.strip().splitlines()
    assert second == said.group(2)
    got, want = first.replace("[", " ").replace("]", " ").split(), \
        said.group(1).replace("[", " ").replace("]", " ").split()
    assert [float(v) for v in got[:2]] == pytest.approx([float(v) for v in want[:2]], abs=1e-7)
    assert float(got[2]) < 1e-6


@pytest.mark.e2e       # the whole pipeline from the wheel: make test-e2e
def test_stepzoo_run_from_the_wheel_writes_the_report(venv, tmp_path):
    config = tmp_path / "tiny.toml"                 # the smallest sweep; tune accepts 1 m
    config.write_text(TINY_SWEEP)
    out = tmp_path / "results"
    proc = subprocess.run([venv / "stepzoo", "run", "--config", str(config), "--out", str(out),
                           "--pos-tol", "1", "-q"], cwd=tmp_path, capture_output=True,
                          text=True, timeout=600)
    assert proc.returncode in (0, 1), proc.stderr[-2000:]     # 1: a plan not exact
    assert proc.stdout.strip() == str(out / "report" / "index.html")
    assert (out / "report" / "index.html").is_file()
