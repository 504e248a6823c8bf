"""The machine a measurement ran on, named one way for ``companion bench`` and ``benchmarks/``.

A speed figure means little without the CPU that made it: the same code and the same command have
taken three times longer on one 2-core AMD EPYC than on another (docs/results.md, "Speed").
Virtual machines often report a bare "AMD EPYC" as the model name, so the CPU family and model
numbers are kept beside it (AMD family 25 is Zen 3 / Zen 4, family 26 Zen 5).
"""

from __future__ import annotations

import os
import platform
from pathlib import Path

CPUINFO = Path("/proc/cpuinfo")


def cpu_model(cpuinfo: Path = CPUINFO) -> str:
    """The first CPU's model name from /proc/cpuinfo with its family and model numbers, else what
    :func:`platform.processor` says (macOS, Windows), else the machine type."""
    fields: dict[str, str] = {}
    try:
        text = cpuinfo.read_text(encoding="utf-8", errors="replace")
    except OSError:
        text = ""
    for line in text.splitlines():
        if not line.strip():
            break  # the end of the first processor's block
        key, _, value = line.partition(":")
        fields.setdefault(key.strip(), value.strip())
    name = fields.get("model name") or platform.processor() or platform.machine() or "unknown CPU"
    if "cpu family" in fields:
        name += f" (family {fields['cpu family']}, model {fields.get('model', '?')})"
    return name


def machine_line() -> str:
    """The line a benchmark prints first: CPU model, logical CPUs, load average, Python."""
    try:
        load = f"load average {os.getloadavg()[0]:.1f}"
    except OSError:
        load = "load average unknown"
    return f"machine: {cpu_model()}, {os.cpu_count()} logical CPUs, {load}, Python {platform.python_version()}"
