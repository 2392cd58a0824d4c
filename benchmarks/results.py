"""benchmarks/RESULTS.md: one `## <title>` section per benchmark, replaced in place."""

from __future__ import annotations

import os
import pathlib
import platform
import re
import statistics
import subprocess

import jax

RESULTS = pathlib.Path(__file__).with_name("RESULTS.md")
HEADER = "# Benchmark results\n\nEach section is written by the command it names.\n"


def write_section(title: str, body: str, path: pathlib.Path = RESULTS) -> None:
    """Replaces (or appends) the section `## title` of RESULTS.md with `body`."""
    text = path.read_text() if path.exists() else HEADER
    block = f"## {title}\n\n{body.strip()}\n"
    pattern = re.compile(rf"^## {re.escape(title)}\n.*?(?=^## |\Z)", re.S | re.M)
    if pattern.search(text):
        text = pattern.sub(lambda _: block + "\n", text, count=1)
    else:
        text = text.rstrip("\n") + "\n\n" + block
    path.write_text(text.rstrip("\n") + "\n")


def report(title: str, body: str, write: bool) -> None:
    """A benchmark module's output: prints `body`; with `write`, also its RESULTS.md section."""
    print(body)
    if write:
        write_section(title, body)


def paired_ratio(ours: list[float], reference: list[float]) -> float:
    """Median over rounds i of ours[i] / reference[i], for rates timed back to back: a load
    that drifts between rounds moves both sides of a pair alike."""
    return statistics.median(a / b for a, b in zip(ours, reference, strict=True))


def hardware() -> str:
    """One line naming the CPU (from lscpu), the core count and the JAX devices."""
    try:
        out = subprocess.run(["lscpu"], capture_output=True, text=True, check=True).stdout
        name = next(ln.split(":", 1)[1].strip() for ln in out.splitlines() if "Model name" in ln)
    except (OSError, subprocess.CalledProcessError, StopIteration):
        name = platform.processor() or "unknown CPU"
    devices = ", ".join(str(d) for d in jax.devices())
    return f"{name}, {os.cpu_count()} cores; JAX devices: {devices}"
