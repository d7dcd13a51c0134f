"""An experiment folder's manifest: ``experiment.mcap``, whose ``/run`` metadata says what produced
the recordings beside it.

The metadata: ``scenario`` "experiment" (so readers tell it from an episode), the experiment's
name, whether it is quick, its settings and budget, the command, the date (UTC) and the machine
(CPU, cores, JAX device, system, package versions). ``scenarios.reproduce`` writes one per table,
``scenarios.sweep`` one per output folder; every run rewrites it. ``analysis`` reads it for the
tables' captions (the hardware) and to mark quick results.
"""

from __future__ import annotations

import datetime
import os
import platform
from pathlib import Path

#: File stem of the manifest recording, and its ``scenario``.
STEM = "experiment"


def machine() -> dict:
    """The hardware and software of this process: cpu, cores, device, device_kind, system, versions."""
    import jax

    from scenarios.episode import package_versions

    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            cpu = next(line.split(":", 1)[1].strip() for line in f if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    device = jax.devices()[0]
    return {"cpu": cpu, "cores": os.cpu_count(), "device": str(device.platform), "device_kind": device.device_kind,
            "system": platform.platform(), "versions": package_versions()}


def write_manifest(where: Path, experiment: str, command: str, settings: dict, *, quick: bool = False,
                   budget: dict | None = None) -> None:
    """Write (or rewrite) ``where/experiment.mcap`` for ``experiment`` run by ``command``."""
    from recorder import Recorder, schema

    where = Path(where)
    meta = {"run_id": f"{where.name}/{STEM}", "scenario": schema.MANIFEST, "experiment": experiment, "quick": quick,
            "budget": budget or {}, "settings": settings, "command": command,
            "date": datetime.datetime.now(datetime.UTC).isoformat(), "machine": machine()}
    where.mkdir(parents=True, exist_ok=True)
    with Recorder(where / STEM, meta, ("mcap",), overwrite=True) as rec:
        rec.finish({"outcome": "success", "steps": 0})
