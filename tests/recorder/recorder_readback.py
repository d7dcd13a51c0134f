"""Recordings read back raw for the recorder tests: every Rerun column, every MCAP message decoded.

A plain module beside the tests (pytest puts this folder on sys.path): `from recorder_readback import ...`.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import rerun.chunk as rc
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory


def rrd_columns(path: Path) -> dict[tuple[str, str], list]:
    """{(entity, column): the column's rows over all chunks, in file order}."""
    cols: dict[tuple[str, str], list] = {}
    for chunk in rc.RrdReader(path).stream().to_chunks():
        batch = chunk.to_record_batch()
        for name in batch.schema.names:
            cols.setdefault((chunk.entity_path, name), []).extend(batch.column(name).to_pylist())
    return cols


def rrd_layouts(path: Path) -> list[set[str]]:
    """The titles of the views of each blueprint stored in a .rrd, in the order they were sent (by the
    wall-clock `log_time` of a blueprint's rows; the reader lists the stores in no set order)."""
    reader = rc.RrdReader(path)
    layouts = []
    for entry in reader.blueprints():
        titles, sent = set(), []
        for chunk in reader.stream(store=entry).to_chunks():
            batch = chunk.to_record_batch()
            sent += batch.column("log_time").to_pylist()
            if "ViewBlueprint:display_name" in batch.schema.names:
                titles |= {row[0] for row in batch.column("ViewBlueprint:display_name").to_pylist()}
        layouts.append((min(sent), titles))
    return [titles for _, titles in sorted(layouts, key=lambda x: x[0])]


def rrd_values(path: Path) -> dict[tuple[str, str, int | None], object]:
    """{(entity, component, step): value}: every component value at its step (None: static), however the
    rows are cut into chunks. Control columns, the timelines and recording properties are left out."""
    values: dict[tuple[str, str, int | None], object] = {}
    for chunk in rc.RrdReader(path).stream().to_chunks():
        if chunk.entity_path.startswith("/__properties"):
            continue
        batch = chunk.to_record_batch()
        steps = [None] * batch.num_rows if chunk.is_static else batch.column("step").to_pylist()
        for name in batch.schema.names:
            if ":" in name:  # Archetype:component
                for step, value in zip(steps, batch.column(name).to_pylist()):
                    key = (chunk.entity_path, name, step)
                    assert key not in values, f"{key} logged twice"
                    values[key] = value
    return values


def mcap_messages(path: Path) -> dict[str, list]:
    """{topic: [(log_time, message)]}: protobuf decoded, JSON parsed."""
    msgs: dict[str, list] = {}
    factory = DecoderFactory()
    with open(path, "rb") as f:
        for schema_, channel, message in make_reader(f).iter_messages():
            if channel.message_encoding == "json":
                decoded = json.loads(message.data)
            else:
                decoded = factory.decoder_for(channel.message_encoding, schema_)(message.data)
            msgs.setdefault(channel.topic, []).append((message.log_time, decoded))
    return msgs


def xyz(points) -> np.ndarray:
    """Foxglove Point3 / Vector3 messages -> (N, 3)."""
    return np.array([[p.x, p.y, p.z] for p in points])
