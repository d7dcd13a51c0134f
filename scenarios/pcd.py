"""Point clouds in the Point Cloud Library's ``.pcd`` format (a ROS or PCL scan), ascii or binary.

A header of ``KEY values`` lines (FIELDS, SIZE, TYPE, COUNT, WIDTH, HEIGHT, POINTS) ends at the
``DATA`` line; then one point per line (ascii) or per packed little-endian record (binary). Only
the fields x, y, z are read, in metres, as written (VIEWPOINT is the sensor's pose, which PCL's
reader does not apply either). Points with a NaN or infinite coordinate are the format's
invalid points (an organized cloud's pixels without a return) and are dropped. ``binary_compressed``
data is the binary records' fields one after the other (all x, then all y, ...), compressed with LZF
(:func:`lzf_decompress`) after two little-endian uint32: the compressed and the raw size.
"""

from __future__ import annotations

import struct

import numpy as np

#: The header's keys that must be present, in the order PCL writes them.
_KEYS = ("FIELDS", "SIZE", "TYPE", "WIDTH", "HEIGHT", "POINTS", "DATA")
#: The header is at most this many bytes (PCL writes a few hundred).
_HEADER_BYTES = 1 << 16


def _header(raw: bytes) -> tuple[dict[str, list[str]], int]:
    """The header's keys -> their words, and the offset of the data after the DATA line."""
    header, offset = {}, 0
    while offset < min(len(raw), _HEADER_BYTES):
        end = raw.find(b"\n", offset)
        end = len(raw) if end < 0 else end
        words = raw[offset:end].decode("ascii", "replace").split()
        offset = end + 1
        if words and not words[0].startswith("#"):
            header[words[0].upper()] = words[1:]
            if words[0].upper() == "DATA":
                return header, offset
    raise ValueError("no DATA line: not a .pcd file")


def _layout(header: dict[str, list[str]]) -> tuple[np.dtype, int]:
    """The numpy record type of one point and the number of points."""
    missing = [key for key in _KEYS if key not in header]
    if missing:
        raise ValueError(f"the header lacks {', '.join(missing)}")
    fields, sizes, types = header["FIELDS"], header["SIZE"], header["TYPE"]
    counts = header.get("COUNT", ["1"] * len(fields))
    if not len(fields) == len(sizes) == len(types) == len(counts):
        raise ValueError("FIELDS, SIZE, TYPE and COUNT differ in length")
    if not {"x", "y", "z"} <= set(fields):
        raise ValueError(f"no x, y, z among the fields {' '.join(fields)}")
    try:
        kinds = [{"F": "f", "I": "i", "U": "u"}[t.upper()] for t in types]
        dtype = np.dtype([(f if f in "xyz" else f"_{i}", f"<{k}{int(s)}", (int(c),))
                          for i, (f, s, k, c) in enumerate(zip(fields, sizes, kinds, counts))])
        points = int(header["POINTS"][0])
    except (KeyError, TypeError, ValueError, IndexError):
        raise ValueError(f"bad SIZE, TYPE, COUNT or POINTS: {sizes} {types} {counts} {header['POINTS']}") from None
    if points < 0:
        raise ValueError(f"POINTS must be >= 0, got {points}")
    return dtype, points


def _records(raw: bytes, offset: int, dtype: np.dtype, points: int, data: str) -> np.ndarray:
    """The points' records (points,) of the data after the header."""
    if data == "binary":
        need = points * dtype.itemsize
        if len(raw) - offset < need:
            raise ValueError(f"{points} points need {need} bytes of binary data, the file holds {len(raw) - offset}")
        return np.frombuffer(raw, dtype, count=points, offset=offset)
    if data == "ascii":
        words = raw[offset:].split()
        width = sum(int(np.prod(dtype[name].shape)) for name in dtype.names)
        if len(words) != points * width:
            raise ValueError(f"{points} points of {width} values need {points * width} ascii values, got {len(words)}")
        values = np.array(words, dtype=np.float64).reshape(points, width)
        flat = np.dtype([(name, "<f8", dtype[name].shape) for name in dtype.names])
        return values.view(flat).reshape(points)
    if data == "binary_compressed":
        if len(raw) - offset < 8:
            raise ValueError("binary_compressed data without its sizes")
        packed, size = struct.unpack_from("<II", raw, offset)
        if size != points * dtype.itemsize:
            raise ValueError(f"{points} points need {points * dtype.itemsize} bytes, the data says {size}")
        fields = lzf_decompress(raw[offset + 8: offset + 8 + packed], size)
        out, start = np.empty(points, dtype), 0
        for name in dtype.names:  # field by field, each (points, count)
            width = dtype[name].itemsize * points
            out[name] = np.frombuffer(fields, dtype[name].base, offset=start,
                                      count=points * int(np.prod(dtype[name].shape))).reshape(out[name].shape)
            start += width
        return out
    raise ValueError(f"unknown DATA {data!r} (ascii, binary or binary_compressed)")


def read_pcd(path: str) -> tuple[np.ndarray, int]:
    """The finite points (P, 3) float64 m of a .pcd file, and how many invalid (NaN) points were
    dropped; ValueError saying what is wrong with the file."""
    with open(path, "rb") as handle:
        raw = handle.read()
    header, offset = _header(raw)
    dtype, points = _layout(header)
    records = _records(raw, offset, dtype, points, header["DATA"][0].lower() if header["DATA"] else "")
    xyz = np.stack([records[axis][:, 0] for axis in "xyz"], axis=-1).astype(np.float64)
    finite = np.all(np.isfinite(xyz), axis=1)
    return xyz[finite], int(points - finite.sum())


def lzf_decompress(data: bytes, size: int) -> bytes:
    """LZF's ``size`` bytes from ``data``: a control byte c < 32 is followed by c + 1 literal bytes;
    otherwise its top 3 bits n (7: plus the next byte) and its low 5 bits with the next byte, o,
    copy n + 2 bytes from o + 1 back in the output (overlapping: a repeated pattern)."""
    out, i = bytearray(), 0
    while i < len(data):
        control = data[i]
        i += 1
        if control < 32:
            out += data[i: i + control + 1]
            i += control + 1
            continue
        if i + (control >> 5 == 7) >= len(data):
            raise ValueError("corrupt binary_compressed data (it ends inside a reference)")
        length = control >> 5
        if length == 7:
            length += data[i]
            i += 1
        start = len(out) - ((control & 31) << 8) - data[i] - 1
        i += 1
        if start < 0:
            raise ValueError("corrupt binary_compressed data (a reference before the start)")
        if start + length + 2 <= len(out):
            out += out[start: start + length + 2]
        else:  # the copy overlaps what it writes: byte by byte
            for k in range(length + 2):
                out.append(out[start + k])
    if len(out) != size:
        raise ValueError(f"corrupt binary_compressed data ({len(out)} bytes, the header says {size})")
    return bytes(out)
