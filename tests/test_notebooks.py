"""The notebooks run top to bottom on the CPU with tiny settings.

Each notebook's `parameters` cell (papermill's convention) is followed by an injected cell
that overrides its settings, then nbclient executes it in a kernel of this interpreter.
The kernel inherits this process's environment (tests/conftest.py: JAX on the CPU, the
shared compilation cache). The committed notebooks carry no outputs. Notebooks that render
take the `gl_backend` fixture (tests/conftest.py): skipped, saying why, without OpenGL.
"""

import json
import pathlib
import re
import sys
import time

import nbclient
import nbformat
import pytest
from jupyter_client.kernelspec import KernelSpecManager
from jupyter_client.manager import KernelManager

NOTEBOOKS = pathlib.Path(__file__).resolve().parents[1] / "notebooks"
KERNEL = "d2c_jax_test"
TIMEOUT_S = 600


def tiny_parameters(name: str, tmp_path: pathlib.Path) -> dict:
    """Settings that keep each notebook to seconds of work (plus compiles)."""
    common = {"INSTALL": False}
    return {
        "01_quickstart.ipynb": {
            **common,
            "PRESET": "tiny",
            "OUT_DIR": str(tmp_path / "run"),
            "FRAME_SIZE": 48,
        },
        "02_seed_sweep.ipynb": {
            **common,
            "PRESET": "tiny",
            "SEEDS": 2,
            "TOTAL_STEPS": None,
            "OUT_ROOT": str(tmp_path / "sweep"),
        },
        "03_environments.ipynb": {
            **common,
            "RANDOM_STEPS": 3,
            "FRAME_WIDTH": 64,
            "FRAME_HEIGHT": 48,
            "OUT_DIR": str(tmp_path / "tour"),
        },
    }[name]


def inject_parameters(nb, params: dict) -> None:
    """Inserts a cell assigning `params` right after the cell tagged `parameters`."""
    index = next(i for i, c in enumerate(nb.cells) if "parameters" in c.metadata.get("tags", []))
    source = "\n".join(f"{k} = {v!r}" for k, v in params.items())
    cell = nbformat.v4.new_code_cell(source)
    cell.metadata["tags"] = ["injected-parameters"]
    nb.cells.insert(index + 1, cell)


def kernel_manager(tmp_path: pathlib.Path) -> KernelManager:
    """A kernel of this interpreter (never another `python3` kernelspec on the machine)."""
    spec_dir = tmp_path / "kernels" / KERNEL
    spec_dir.mkdir(parents=True)
    spec = {
        "argv": [sys.executable, "-m", "ipykernel_launcher", "-f", "{connection_file}"],
        "display_name": KERNEL,
        "language": "python",
    }
    (spec_dir / "kernel.json").write_text(json.dumps(spec))
    specs = KernelSpecManager(kernel_dirs=[str(tmp_path / "kernels")])
    return KernelManager(kernel_name=KERNEL, kernel_spec_manager=specs)


def run_notebook(name: str, tmp_path: pathlib.Path):
    nb = nbformat.read(NOTEBOOKS / name, as_version=4)
    inject_parameters(nb, tiny_parameters(name, tmp_path))
    client = nbclient.NotebookClient(
        nb,
        km=kernel_manager(tmp_path),
        timeout=TIMEOUT_S,
        resources={"metadata": {"path": str(tmp_path)}},
    )
    start = time.perf_counter()
    client.execute()
    print(f"{name}: executed in {time.perf_counter() - start:.1f} s")
    return nb


def outputs(nb, output_type: str) -> list:
    return [
        o
        for c in nb.cells
        if c.cell_type == "code"
        for o in c.outputs
        if o.output_type == output_type
    ]


@pytest.mark.parametrize("name", sorted(p.name for p in NOTEBOOKS.glob("*.ipynb")))
def test_committed_notebook_is_clean(name):
    """Outputs stripped; a Colab badge first, for the repository of REPO_URL; one
    `parameters` cell; no algorithm code (training goes through the package)."""
    nb = nbformat.read(NOTEBOOKS / name, as_version=4)
    nbformat.validate(nb)
    code = [c for c in nb.cells if c.cell_type == "code"]
    assert all(not c.outputs and c.execution_count is None for c in code)
    (params,) = [c for c in code if "parameters" in c.metadata.get("tags", [])]
    repo_url = re.search(r'^REPO_URL = "https://github.com/([^"]+)"', params.source, re.M)
    assert repo_url, "the parameters cell sets REPO_URL"
    badge = f"https://colab.research.google.com/github/{repo_url[1]}/blob/main/notebooks/{name}"
    assert nb.cells[0].cell_type == "markdown" and badge in nb.cells[0].source
    assert not any(word in c.source for c in code for word in ("jax.grad", "optax", "flax"))


def test_quickstart_notebook(tmp_path, gl_backend):  # renders a video
    nb = run_notebook("01_quickstart.ipynb", tmp_path)
    run = tmp_path / "run"
    assert (run / "metrics.jsonl").exists()
    assert (run / "notebook" / "success.png").exists()
    assert (run / "policy.gif").exists()
    images = [
        o for o in outputs(nb, "display_data") if "image/png" in o.data or "image/gif" in o.data
    ]
    assert len(images) >= 3  # success curve, curriculum, policy video


@pytest.mark.slow  # a vmapped-seed training run: the sweep tests cover the path
def test_seed_sweep_notebook(tmp_path):
    nb = run_notebook("02_seed_sweep.ipynb", tmp_path)
    (run,) = (tmp_path / "sweep").glob("*/metrics.jsonl")  # both λ arms in one run
    last = json.loads(run.read_text().splitlines()[-1])
    assert len(last["eval/success"]) == 2 * 2  # 2 arms x 2 seeds
    text = "".join(o.get("text", "") for o in outputs(nb, "stream"))
    assert "±" in text


@pytest.mark.slow  # builds and renders all six envs: minutes cold on 2 cores
def test_environments_notebook(tmp_path, gl_backend):  # renders every env
    nb = run_notebook("03_environments.ipynb", tmp_path)
    import envs

    gifs = {p.stem for p in (tmp_path / "tour").glob("*.gif")}
    assert gifs >= set(envs.ENV_NAMES)
    assert len(outputs(nb, "display_data")) >= 2 * len(envs.ENV_NAMES)
