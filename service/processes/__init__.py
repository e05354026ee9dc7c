"""The processes the service runs as jobs: ``run``, ``reconstruct``, ``scan``, ``compare``,
``plan``, ``plot-scan``, ``plot-from-cloud`` and ``validate``, one module each.

Each is a thin adapter over one :mod:`treesim` function: its inputs (files, by kind), the
JSON Schema of its parameters (generated from the parameter model,
:func:`treesim.params.json_schema`, plus the preset names the CLI takes), how a request's
parameters become the parameter dataclass (:func:`treesim.params.merge` decides), and the
call that runs it in a job's process. Each module ends in its ``PROCESS``, described next
to its code; :mod:`.base` holds what they share and :mod:`.sources` where ``plan`` and
``plot-scan`` get their plot. A new process is one more module and one more name in
:data:`PROCESSES`; nothing else in the service names a parameter.
"""

from __future__ import annotations

from . import compare, plan, plot_from_cloud, plot_scan, reconstruct, run, scan, validate
from .base import Input, Process, check_parameters

__all__ = ["PROCESSES", "Input", "Process", "check_parameters"]

#: The processes by id, in the order the API lists them.
PROCESSES: dict[str, Process] = {
    m.PROCESS.id: m.PROCESS
    for m in (run, reconstruct, scan, compare, plan, plot_scan, plot_from_cloud, validate)
}
