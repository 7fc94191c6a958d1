"""The distribution as users install it: dependencies declared where the code imports them, the libraries on
their core dependencies alone, and (marked slow) the wheel installed into a fresh environment, run from an
empty directory."""

from __future__ import annotations

import ast
import functools
import importlib.metadata
import json
import os
import re
import shutil
import subprocess
import sys
import sysconfig
import tomllib
import venv
from pathlib import Path

import pytest
from test_readme import ON_THE_WHEEL, SECTIONS

ROOT = Path(__file__).resolve().parents[1]
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())
PROJECT = PYPROJECT["project"]["name"]
LIBRARIES = ("hbni_infra", "hbni_pyro", "classifiers", "decpomdp")
OURS = {*LIBRARIES, "experiments", "benchmarks"}  # benchmarks: the checkout's own scripts, never installed
EXPERIMENTS_ONLY = ("hydra", "omegaconf", "hydra_plugins", "submitit", "matplotlib", "skimage", "arviz", "sklearn")
"""Modules only the experiments (or optional library features) use: the libraries import without them."""
MODULE_TO_DIST = {"torchvision": "torchvision", "rclpy": None, "launch": None, "launch_ros": None, "paynt": "paynt"}
"""Import names that the running environment may not have installed (None: not on PyPI, a ROS 2 system
package: the node's ``rclpy``, its launch file's ``launch`` and ``launch_ros``)."""


def _requirement_name(spec: str) -> tuple[str, list[str]]:
    match = re.match(r"\s*([A-Za-z0-9][A-Za-z0-9._-]*)\s*(?:\[([^\]]*)\])?", spec)
    assert match, spec
    extras = [e.strip() for e in (match.group(2) or "").split(",") if e.strip()]
    return _normal(match.group(1)), extras


def _normal(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def declared(*extras: str) -> set[str]:
    """Distribution names that the core install plus ``extras`` bring (the project's own extras expanded)."""
    optional = PYPROJECT["project"]["optional-dependencies"]
    out: set[str] = set()
    todo = [*PYPROJECT["project"]["dependencies"], *(s for e in extras for s in optional[e])]
    while todo:
        name, inner = _requirement_name(todo.pop())
        if name == _normal(PROJECT):
            todo += [s for e in inner for s in optional[e]]
        else:
            out.add(name)
    return out


def imports(path: Path, top_level_only: bool = False) -> set[str]:
    """Top-level names of the absolute imports in ``path`` (also inside functions unless ``top_level_only``)."""
    tree = ast.parse(path.read_text(), str(path))
    nodes = tree.body if top_level_only else ast.walk(tree)
    names = set()
    for node in nodes:
        if isinstance(node, ast.Try) and top_level_only:  # an optional import guarded by try/except ImportError
            continue
        if isinstance(node, ast.Import):
            names |= {alias.name.split(".")[0] for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module.split(".")[0])
    return names - set(sys.stdlib_module_names) - OURS - {"__future__"}


@functools.cache
def _installed() -> dict[str, list[str]]:
    return importlib.metadata.packages_distributions()


def distribution(module: str) -> str | None:
    if module in MODULE_TO_DIST:
        return MODULE_TO_DIST[module]
    dists = _installed().get(module)
    assert dists, f"{module!r} is imported but no installed distribution provides it"
    return _normal(dists[0])


def undeclared(folders: tuple[str, ...], allowed: set[str], top_level_only: bool = False) -> dict[str, list[str]]:
    """Per module of ``folders``, the imported distributions not in ``allowed`` (the folders' own helper modules,
    such as the tests' shared fixtures, count as local)."""
    bad: dict[str, list[str]] = {}
    for folder in folders:
        paths = sorted((ROOT / folder).rglob("*.py"))
        local = {p.stem for p in paths} | {p.parent.name for p in paths}
        for path in paths:
            missing = sorted(
                m
                for m in imports(path, top_level_only) - local
                if (d := distribution(m)) is not None and d not in allowed
            )
            if missing:
                bad[str(path.relative_to(ROOT))] = missing
    return bad


def test_the_libraries_import_only_core_dependencies_at_module_level():
    """What ``import hbni_pyro, classifiers, decpomdp`` loads is in the core install (OpenCV: the user's own or
    the ``opencv`` extra, checked with a clear message in ``classifiers/__init__``)."""
    assert not undeclared(LIBRARIES, declared("opencv"), top_level_only=True)


def test_every_import_is_declared_where_it_is_used():
    optional = set(PYPROJECT["project"]["optional-dependencies"])
    assert not undeclared(LIBRARIES, declared(*(optional - {"dev"})))
    assert not undeclared(("experiments",), declared("experiments"))
    assert not undeclared(("tests", "benchmarks"), declared(*optional))


def test_the_experiments_extras_are_not_core_dependencies():
    core = declared()
    for name in ("hydra-core", "hydra-joblib-launcher", "hydra-submitit-launcher", "matplotlib", "scikit-image"):
        assert name not in core and name in declared("experiments")
    assert not any(n.startswith("opencv") for n in core) and "scipy" in core


BLOCKER = """
import importlib.abc, sys
BLOCKED = set(sys.argv[1].split(","))
class Blocker(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in BLOCKED:
            raise ImportError(f"{name} is blocked: not a core dependency")
sys.meta_path.insert(0, Blocker())
"""


def core_only_script(body: str, blocked: tuple[str, ...] = EXPERIMENTS_ONLY) -> list[str]:
    """A ``python -c`` command that runs ``body`` with ``blocked`` modules made unimportable."""
    return ["-c", BLOCKER + body, ",".join(blocked)]


README_QUICKSTART = re.findall(r"```python\n(.*?)```", (ROOT / "README.md").read_text(), re.S)[0]


def test_the_libraries_run_the_readme_quickstart_without_the_experiments_extras(tmp_path):
    body = "import hbni_pyro, classifiers, decpomdp\n" + README_QUICKSTART
    out = subprocess.run(
        [sys.executable, *core_only_script(body)],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        timeout=300,
    )
    assert out.returncode == 0, out.stderr
    assert "MacroObservation(label=0" in out.stdout


def test_hbni_pyro_and_decpomdp_need_no_opencv(tmp_path):
    body = "import hbni_pyro, decpomdp, hbni_infra\nwith hbni_infra.threads(1): pass\nprint('ok')"
    out = subprocess.run(
        [sys.executable, *core_only_script(body, (*EXPERIMENTS_ONLY, "cv2"))],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        timeout=120,
    )
    assert out.returncode == 0 and out.stdout.strip() == "ok", out.stderr
    out = subprocess.run(
        [sys.executable, *core_only_script("import classifiers", ("cv2",))],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        timeout=120,
    )
    assert out.returncode != 0 and "hbni-pyro[opencv]" in out.stderr


def test_each_library_has_the_distributions_version():
    import classifiers
    import decpomdp
    import experiments
    import hbni_pyro

    versions = {m.__version__ for m in (hbni_pyro, classifiers, decpomdp, experiments)}
    assert len(versions) == 1 and re.fullmatch(r"\d+\.\d+\.\d+", versions.pop())


@pytest.fixture(scope="module")
def source(tmp_path_factory) -> Path:
    """A copy of the checkout's tracked files (what a clean clone holds)."""
    source = tmp_path_factory.mktemp("source") / "source"
    tracked = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True).stdout
    for name in filter(None, tracked.decode().split("\0")):
        target = source / name
        target.parent.mkdir(parents=True, exist_ok=True)
        if (ROOT / name).is_symlink():
            target.symlink_to(os.readlink(ROOT / name))
        elif (ROOT / name).is_file():
            shutil.copy2(ROOT / name, target)
    return source


@pytest.fixture(scope="module")
def installed(tmp_path_factory, source) -> Path:
    """A fresh virtual environment with the project's wheel installed (no network: its dependencies are the ones
    this interpreter has, seen through a path file); returns its ``bin`` folder."""
    work = tmp_path_factory.mktemp("install")
    pip = [sys.executable, "-m", "pip", "--disable-pip-version-check", "-q"]
    subprocess.run(
        [*pip, "wheel", "--no-deps", "--no-build-isolation", "-w", str(work / "dist"), str(source)],
        check=True,
        capture_output=True,
    )
    (wheel,) = (work / "dist").glob("*.whl")
    env_dir = work / "venv"
    venv.create(env_dir, with_pip=False)
    python = env_dir / "bin" / "python"
    purelib = subprocess.run(
        [python, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
        capture_output=True,
        text=True,
        check=True,
    ).stdout.strip()
    (Path(purelib) / "dependencies.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    subprocess.run([*pip, "--python", str(python), "install", "--no-deps", "--no-index", str(wheel)], check=True)
    return env_dir / "bin"


def _run(command: list, cwd: Path, **kw) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "HBNI_PYRO_ROOT")}
    return subprocess.run(command, cwd=cwd, capture_output=True, text=True, env=env, timeout=600, **kw)


@pytest.mark.slow
def test_the_installed_wheel_imports_from_itself_with_the_core_dependencies(installed, tmp_path):
    body = (
        "import json, hbni_pyro, classifiers, decpomdp, hbni_infra\n"
        "print(json.dumps([m.__file__ for m in (hbni_pyro, classifiers, decpomdp, hbni_infra)]))"
    )
    out = _run([installed / "python", *core_only_script(body)], tmp_path)
    assert out.returncode == 0, out.stderr
    assert all(str(installed.parent) in f for f in json.loads(out.stdout))
    names = {p.name for p in Path(json.loads(out.stdout)[0]).parents[1].iterdir() if p.suffix != ".pth"}
    ours = {n for n in names if not n.endswith((".dist-info", "__pycache__")) and not n.startswith("_")}
    assert ours == {"hbni_pyro", "classifiers", "decpomdp", "experiments", "hbni_infra"}  # no other top-level name


@pytest.mark.slow
def test_the_console_script_runs_an_experiment_from_an_empty_directory(installed, tmp_path):
    helped = _run([installed / "hbni-pyro", "--help"], tmp_path)
    assert helped.returncode == 0 and "hbni_toy" in helped.stdout and "dpomdp_benchmarks" in helped.stdout
    ran = _run(
        [
            installed / "hbni-pyro",
            "experiment=hbni_toy",
            "hbni.fit.num_chains=2",
            "hbni.fit.num_samples=50",
            "hbni.fit.warmup_steps=50",
            "progress=false",
        ],
        tmp_path,
    )
    assert ran.returncode == 0, ran.stderr
    (run_dir,) = (tmp_path / "outputs" / "hbni_toy").iterdir()
    assert str(run_dir) in ran.stdout + ran.stderr  # the entry point says where it wrote
    loaded = _run(
        [
            installed / "python",
            "-c",
            "from experiments import latest_run, load_run\n"
            "run = load_run(latest_run('hbni_toy'))\n"
            "print(run.run_dir, run.posterior.samples['theta'].shape[:2], run.metrics['theta_true'])",
        ],
        tmp_path,
    )
    assert loaded.returncode == 0, loaded.stderr
    assert loaded.stdout.split()[0] == str(run_dir) and "[1.0, 6.0, 20.0]" in loaded.stdout
    assert not list(installed.parent.rglob("outputs"))  # nothing was written into the environment


@pytest.mark.slow
def test_pytest_runs_from_an_unpacked_sdist_with_its_docs_and_license_metadata(source, tmp_path):
    """The sdist holds the docs the README links, every test with its helpers (``conftest.py``, data) and
    ``py.typed``; pytest runs a few test files from it, on the unpacked packages; its metadata carries an SPDX
    license expression and both licence files, and the build warns about no license table."""
    import tarfile

    build = subprocess.run(
        [sys.executable, "-c", "import setuptools.build_meta as b; print(b.build_sdist('dist'))"],
        cwd=source,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert build.returncode == 0, build.stderr
    assert "project.license" not in build.stdout + build.stderr  # no deprecated license table
    with tarfile.open(source / "dist" / build.stdout.strip().splitlines()[-1]) as tar:
        tar.extractall(tmp_path, filter="data")
    (unpacked,) = tmp_path.iterdir()
    links = re.findall(r"\]\(((?:docs)/[^)]+)\)", (unpacked / "README.md").read_text())
    assert links and all((unpacked / link).exists() for link in links)
    tracked_tests = {p.relative_to(source) for p in (source / "tests").rglob("*") if p.is_file()}
    assert {p.relative_to(unpacked) for p in (unpacked / "tests").rglob("*") if p.is_file()} >= tracked_tests
    assert all((unpacked / package / "py.typed").is_file() for package in (*LIBRARIES, "experiments"))
    meta = (unpacked / "PKG-INFO").read_text()
    assert "License-Expression: MIT AND GPL-3.0-only" in meta
    assert "License-File: LICENSE" in meta and "License-File: decpomdp/dpomdp/problems/COPYING" in meta
    files = ["tests/hbni_infra/test_checks.py", "tests/decpomdp/test_executor.py", "tests/hbni_pyro/test_live.py"]
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "HBNI_PYRO_ROOT")}
    ran = subprocess.run(
        [sys.executable, "-m", "pytest", "-n", "0", "-p", "no:randomly", "-m", "not slow", "-q", *files],
        cwd=unpacked,
        capture_output=True,
        text=True,
        env=env,
        timeout=600,
    )
    assert ran.returncode == 0 and "[100%]" in ran.stdout, ran.stdout[-3000:] + ran.stderr[-3000:]
    where = subprocess.run(
        [sys.executable, "-c", "import hbni_pyro; print(hbni_pyro.__file__)"],
        cwd=unpacked,
        capture_output=True,
        text=True,
        env=env,
    )
    assert where.stdout.strip() == str(unpacked / "hbni_pyro" / "__init__.py")  # the sdist's code was tested


@pytest.mark.slow
def test_the_readme_robot_install_runs_the_robot_blocks_from_the_wheel(installed, tmp_path):
    """The README's robot install is the core install plus the ``opencv`` extra: from the wheel, without OpenCV the
    robot blocks stop at ``classifiers`` with an error naming the extra; with it (the extra's wheel, seen through the
    environment's path file) they run, without Hydra or matplotlib; and the node's console script answers ``--help``
    without OpenCV or ROS 2."""
    readme = (ROOT / "README.md").read_text()
    assert 'pip install ".[opencv]"         # robot' in readme
    (robot,) = SECTIONS[ON_THE_WHEEL]  # the section's blocks, one continuing the other (tests/test_readme.py)
    without = _run([installed / "python", *core_only_script(robot, (*EXPERIMENTS_ONLY, "cv2"))], tmp_path)
    assert without.returncode != 0 and "hbni-pyro[opencv]" in without.stderr, without.stderr[-2000:]
    ran = _run([installed / "python", *core_only_script(robot)], tmp_path)
    assert ran.returncode == 0, ran.stderr[-3000:]
    assert "frames 0-" in ran.stdout and "-> " in ran.stdout
    helped = _run(
        [
            installed / "python",
            *core_only_script(
                "from experiments.ros_node import main\nmain(['--help'])", (*EXPERIMENTS_ONLY, "cv2", "rclpy")
            ),
        ],
        tmp_path,
    )
    assert helped.returncode == 0 and "--ros-args -p NAME:=VALUE" in " ".join(helped.stdout.split()), helped.stderr
    assert (installed / "hbni-ros-node").is_file()
