"""Repository-level checks: README commands, CI script, demo."""

import pathlib
import subprocess
import sys

ROOT = pathlib.Path(__file__).resolve().parents[1]


def readme_commands() -> list[str]:
    """The commands of the README's first code block."""
    text = (ROOT / "README.md").read_text()
    block = text.split("```bash\n", 1)[1].split("```", 1)[0]
    return [line for line in block.splitlines() if line.strip()]


def test_readme_opens_with_install_and_test_commands():
    install, test = readme_commands()
    assert "pip install -e" in install
    assert "pytest" in test


def test_ci_runs_exactly_the_readme_test_command():
    ci_lines = (ROOT / ".ci" / "run").read_text().splitlines()
    assert readme_commands()[1] in ci_lines


def run_demo(out_dir, episodes: int) -> subprocess.CompletedProcess:
    args = ["--out", str(out_dir), "--episodes", str(episodes)]
    return subprocess.run(
        [sys.executable, "-m", "d2c_jax.demo", *args],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=300,
    )


def test_demo_writes_picture(tmp_path):
    out = run_demo(tmp_path, 4)
    assert out.returncode == 0, out.stderr
    png = tmp_path / "random_rollouts.png"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_demo_bad_input_exits_2(tmp_path):
    out = run_demo(tmp_path, 0)
    assert out.returncode == 2
    assert out.stderr.splitlines()[0].startswith("error: --episodes must be positive")


# --- the package's layout (issue 16) -----------------------------------------------------

LAYERS = ("core", "curricula", "viewing", "training")  # each may import only those before it


def d2c_imports(path: pathlib.Path) -> set[str]:
    """The d2c_jax modules a file imports, as dotted names (`from d2c_jax.x import y` gives
    d2c_jax.x and d2c_jax.x.y)."""
    import ast

    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names |= {a.name for a in node.names if a.name.startswith("d2c_jax")}
        elif isinstance(node, ast.ImportFrom) and (node.module or "").startswith("d2c_jax"):
            names |= {node.module} | {f"{node.module}.{a.name}" for a in node.names}
    return names


def test_layers_import_only_the_layers_below_them():
    """core <- curricula <- viewing (drawing) <- training: no layer imports a later one, so
    `ls d2c_jax` reads as the design and the import graph has no cycle between layers."""
    for i, layer in enumerate(LAYERS):
        later = LAYERS[i + 1 :]
        for path in sorted((ROOT / "d2c_jax" / layer).glob("*.py")):
            bad = [
                name
                for name in d2c_imports(path)
                if any(name.startswith(f"d2c_jax.{other}") for other in later)
            ]
            assert not bad, f"{path.relative_to(ROOT)} imports {bad} from a later layer"


def test_no_function_is_longer_than_60_lines():
    """ARCHITECTURE.md: at most 60 lines of body (docstring excluded), nested functions
    counted in the function that encloses them."""
    import ast

    def body_lines(fn) -> int:
        body = fn.body
        has_doc = isinstance(body[0], ast.Expr) and isinstance(
            getattr(body[0], "value", None), ast.Constant
        )
        first = body[1] if has_doc and len(body) > 1 else body[0]
        return 0 if has_doc and len(body) == 1 else fn.end_lineno - first.lineno + 1

    def outermost_functions(tree):
        stack = list(ast.iter_child_nodes(tree))
        while stack:
            node = stack.pop()
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                yield node  # its nested functions count towards it: not descended into
            else:
                stack.extend(ast.iter_child_nodes(node))

    long = [
        f"{path.relative_to(ROOT)}:{fn.lineno} {fn.name} ({body_lines(fn)} lines)"
        for folder in ("d2c_jax", "envs", "benchmarks")
        for path in sorted((ROOT / folder).rglob("*.py"))
        for fn in outermost_functions(ast.parse(path.read_text()))
        if body_lines(fn) > 60
    ]
    assert not long, long


def test_the_flat_module_names_of_earlier_versions_still_import():
    """ARCHITECTURE.md's contract paths, each the very module it moved to, imported in a
    fresh interpreter (so the alias mechanism, not an earlier import, resolves them)."""
    script = """
import importlib
import d2c_jax
from d2c_jax import matching, classifier
import d2c_jax.trainer
import d2c_jax.her as her
from d2c_jax.curriculum import propose
assert matching.auction and classifier.p_pseudo and classifier.loss and her.relabel
assert d2c_jax.trainer.make_train_step and propose
for old, new in d2c_jax._FLAT_NAMES.items():
    module = importlib.import_module(f"d2c_jax.{old}")
    assert module is importlib.import_module(new), old
    assert module.__spec__.name == new and module.__name__ == new, old
    assert getattr(d2c_jax, old) is module
print("ok")
"""
    out = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, cwd=ROOT, timeout=300
    )
    assert out.returncode == 0 and out.stdout.strip() == "ok", out.stderr
