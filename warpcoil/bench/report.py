"""Shared pieces of the benchmarks: timing, markdown tables, the machine line."""

from __future__ import annotations

import os
import platform
import statistics
import time
from pathlib import Path
from typing import Callable

import warp as wp

from ..recorder.atomic import write_text_atomic


def machine() -> str:
    """One line naming the machine and the Warp device the numbers come from."""
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            cpu = next(line.split(":", 1)[1].strip() for line in f if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    device = wp.get_device()
    return (f"{cpu}, {os.cpu_count()} cores, Python {platform.python_version()}, Warp {wp.config.version}, "
            f"device {device.alias} ({device.name})")


def timed(fn: Callable[[], object], repeats: int) -> tuple[object, float]:
    """(last result, median wall time in s over ``repeats`` runs)."""
    times, result = [], None
    for _ in range(repeats):
        start = time.perf_counter()
        result = fn()
        times.append(time.perf_counter() - start)
    return result, statistics.median(times)


def markdown_table(header: list[str], rows: list[list]) -> str:
    def cell(v):
        if isinstance(v, float):
            return f"{v:.3g}"
        return str(v)

    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(cell(v) for v in row) + " |" for row in rows]
    return "\n".join(lines)


def write_report(path: Path, title: str, command: str, sections: list[str]) -> None:
    text = f"# {title}\n\nCommand: `{command}`\n\nMachine: {machine()}\n\n" + "\n\n".join(sections) + "\n"
    write_text_atomic(path, text)
