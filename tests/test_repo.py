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
        [sys.executable, "-m", "d2c_jax.viewing.demo", *args],
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
