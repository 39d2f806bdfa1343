"""The machine a bench ran on, as ordered (name, value) rows for the document's first table."""

from __future__ import annotations

import contextlib
import importlib.metadata
import os
import platform
import subprocess
import sys
from pathlib import Path

PACKAGES = (
    "aslam",
    "numpy",
    "opencv-python-headless",
    "pyrender",
    "PyOpenGL",
    "trimesh",
    "mcap",
    "mcap-ros2-support",
    "matplotlib",
    "typer",
    "rich",
)

_GL_PROBE = (
    "from aslam.recorder.render import select_platform\n"
    "p = select_platform()\n"
    "import pyrender\n"
    "r = pyrender.OffscreenRenderer(8, 8)\n"
    "from OpenGL.GL import GL_RENDERER, GL_VERSION, glGetString\n"
    "print(p, '|', glGetString(GL_RENDERER).decode(), '|', glGetString(GL_VERSION).decode())\n"
    "r.delete()\n"
)
"""Run in a child process: a GL context in the bench's own process would outlive its use."""


def machine(root: Path) -> list[list[str]]:
    """CPU, cores, RAM, OS, Python, OpenGL, package versions and the commit of ``root``, in that order."""
    info: list[list[str]] = []
    cpuinfo = Path("/proc/cpuinfo").read_text() if Path("/proc/cpuinfo").exists() else ""
    models = [line.split(":", 1)[1].strip() for line in cpuinfo.splitlines() if line.startswith("model name")]
    info.append(["CPU", models[0] if models else platform.processor() or "unknown"])
    usable = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    info.append(["cores", f"{usable} usable ({os.cpu_count()} online)"])
    meminfo = Path("/proc/meminfo").read_text() if Path("/proc/meminfo").exists() else ""
    for line in meminfo.splitlines():
        if line.startswith("MemTotal:"):
            info.append(["RAM", f"{int(line.split()[1]) / 2**20:.1f} GiB"])
    info.append(["OS", f"{platform.system()} {platform.release()} ({platform.machine()})"])
    info.append(["Python", platform.python_version()])
    probe = subprocess.run([sys.executable, "-c", _GL_PROBE], capture_output=True, text=True, check=False)
    info.append(
        ["OpenGL", probe.stdout.strip().replace("|", "·") if probe.returncode == 0 else "probe failed"]
    )
    versions = []
    for package in PACKAGES:
        with contextlib.suppress(importlib.metadata.PackageNotFoundError):
            versions.append(f"{package} {importlib.metadata.version(package)}")
    info.append(["packages", ", ".join(versions)])
    git = subprocess.run(
        ["git", "-C", str(root), "rev-parse", "--short", "HEAD"], capture_output=True, text=True
    )
    dirty = subprocess.run(["git", "-C", str(root), "status", "--porcelain"], capture_output=True, text=True)
    if git.returncode == 0:
        info.append(
            ["commit", git.stdout.strip() + (" + uncommitted changes" if dirty.stdout.strip() else "")]
        )
    return info


def load_average() -> str:
    try:
        return ", ".join(f"{v:.2f}" for v in os.getloadavg())
    except OSError:
        return "unknown"
