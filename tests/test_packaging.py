"""What a non-editable install receives: the wheel that `pip install .` and Colab's
`pip install git+...` (notebooks/) build must hold every module and the env models.

An editable install (`pip install -e`, what CI and the README use) imports from the
checkout, so only a built wheel shows what a user outside a checkout receives.
"""

import pathlib
import shutil
import subprocess
import sys
import zipfile

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]


def shipped_sources() -> set[str]:
    """Paths (relative to the checkout) of every module and env model a wheel must hold."""
    files = [
        *ROOT.glob("d2c_jax/**/*.py"),
        *ROOT.glob("envs/**/*.py"),
        *ROOT.glob("envs/xmls/*.xml"),
    ]
    return {f.relative_to(ROOT).as_posix() for f in files if "__pycache__" not in f.parts}


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> pathlib.Path:
    """A wheel built from a clean copy of the sources: setuptools reuses a checkout's
    build/ folder, whose stale files would hide a module the configuration leaves out."""
    source, out = tmp_path_factory.mktemp("source"), tmp_path_factory.mktemp("wheel")
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(ROOT / name, source / name)
    for package in ("d2c_jax", "envs"):
        shutil.copytree(
            ROOT / package, source / package, ignore=shutil.ignore_patterns("__pycache__")
        )
    cmd = [sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w", str(out), str(source)]
    built = subprocess.run(cmd, capture_output=True, text=True)
    assert built.returncode == 0, built.stderr
    (wheel_file,) = out.glob("d2c_jax-*.whl")
    return wheel_file


def test_the_wheel_holds_every_module_and_env_model(wheel):
    names = set(zipfile.ZipFile(wheel).namelist())
    sources = shipped_sources()
    assert {"d2c_jax/core/sac.py", "d2c_jax/training/cli.py", "envs/xmls/ant.xml"} <= sources
    assert sorted(sources - names) == []


def test_the_installed_wheel_imports_and_builds_an_env_outside_the_checkout(wheel, tmp_path):
    """Installed alone (dependencies from this environment), the package imports from the
    install, not from the checkout, and builds an env from its packaged model."""
    target = tmp_path / "site"
    install = [sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--target", str(target)]
    installed = subprocess.run([*install, str(wheel)], capture_output=True, text=True)
    assert installed.returncode == 0, installed.stderr
    # This environment's editable install of the checkout answers imports by name through
    # a finder of its own: the probe drops it, so only the installed copy can be found.
    probe = (
        "import sys\n"
        "editable = lambda f: 'editable' in getattr(f, '__module__', '') + repr(f)\n"
        "sys.meta_path[:] = [f for f in sys.meta_path if not editable(f)]\n"
        "sys.path_hooks[:] = [h for h in sys.path_hooks if not editable(h)]\n"
        "sys.path_importer_cache.clear()\n"
        "import d2c_jax, envs, d2c_jax.training.cli, d2c_jax.curricula, d2c_jax.viewing.render\n"
        "print(d2c_jax.__file__); print(envs.make('ant').obs_dim)\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", probe],
        cwd=tmp_path,
        env={"PYTHONPATH": str(target), "JAX_PLATFORMS": "cpu", "PATH": "/usr/bin:/bin"},
        capture_output=True,
        text=True,
    )
    assert done.returncode == 0, done.stderr
    module_file, obs_dim = done.stdout.split()
    assert pathlib.Path(module_file).is_relative_to(target)
    assert obs_dim == "29"
