"""`recorder.mcap_scan` against the `mcap` package, for every chunk compression and for cut-off files."""

from __future__ import annotations

import json

import foxglove
import pytest
from foxglove.mcap import MCAPCompression, MCAPWriteOptions
from mcap.reader import make_reader

from recorder import mcap_scan

COMPRESSIONS = {"zstd": MCAPCompression.Zstd, "lz4": MCAPCompression.Lz4, "none": None}


def write(path, compression) -> None:
    ctx = foxglove.Context()
    options = MCAPWriteOptions(compression=compression, chunk_size=2000)  # several chunks
    with foxglove.open_mcap(str(path), context=ctx, writer_options=options) as writer:
        writer.write_metadata("run", {"seed": "3", "name": '"x"'})
        a = foxglove.Channel("/a", schema={"type": "object"}, context=ctx)
        b = foxglove.Channel("/b", schema={"type": "object"}, context=ctx)
        for k in range(100):
            a.log(json.dumps({"k": k, "pad": "a" * 50}).encode(), log_time=1000 + k)
            b.log(json.dumps({"k": -k}).encode(), log_time=1000 + k)


@pytest.mark.parametrize("name", COMPRESSIONS)
def test_scan_matches_the_mcap_package(tmp_path, name):
    path = tmp_path / f"{name}.mcap"
    write(path, COMPRESSIONS[name])
    found = mcap_scan.scan(path, ["/a"])
    with open(path, "rb") as f:
        reader = make_reader(f)
        expected = [(m.log_time, m.data) for _, _, m in reader.iter_messages(topics=["/a"])]
        metadata = {m.name: m.metadata for m in reader.iter_metadata()}
    assert found.messages == {"/a": expected} and len(expected) == 100
    assert found.metadata == metadata == {"run": {"seed": "3", "name": '"x"'}}
    assert found.footer


def test_cut_files_give_a_prefix_of_the_messages(tmp_path):
    path = tmp_path / "full.mcap"
    write(path, MCAPCompression.Zstd)
    data = path.read_bytes()
    full = mcap_scan.scan(path, ["/a", "/b"]).messages
    counts = []
    for cut in range(len(mcap_scan.MAGIC), len(data), max(1, len(data) // 40)):
        part = tmp_path / "part.mcap"
        part.write_bytes(data[:cut])
        found = mcap_scan.scan(part, ["/a", "/b"])
        assert not found.footer
        for topic, messages in found.messages.items():
            assert messages == full[topic][:len(messages)]
        counts.append(len(found.messages["/a"]))
    assert counts == sorted(counts) and counts[0] == 0 and any(0 < c < 100 for c in counts)


def test_not_an_mcap(tmp_path):
    path = tmp_path / "x.mcap"
    path.write_bytes(b"hello")
    with pytest.raises(mcap_scan.NotMcap):
        mcap_scan.scan(path, ["/a"])
