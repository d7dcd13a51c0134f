"""Point clouds in the Point Cloud Library's ``.pcd`` format (a ROS or PCL scan), read with pypcd4.

Every data kind of the format is read (ascii, binary, binary_compressed). Only the fields x, y, z
are kept, in metres, as written (VIEWPOINT is the sensor's pose, which PCL's reader does not apply
either). Points with a NaN coordinate are the format's invalid points (an organized cloud's pixels
without a return); ``scenarios.obstacle_file`` drops them.
"""

from __future__ import annotations

import numpy as np


def read_pcd(path: str) -> np.ndarray:
    """The points (P, 3) float64 m of a .pcd file, invalid ones (NaN) included; ValueError saying
    what is wrong with the file (the reader's own first line else)."""
    from pypcd4 import PointCloud

    try:
        cloud = PointCloud.from_path(path)
    except Exception as err:  # the reader's errors, whatever their kind, become one line
        raise ValueError(_reason(err)) from None
    if not {"x", "y", "z"} <= set(cloud.fields):
        raise ValueError(f"no x, y, z among the fields {' '.join(cloud.fields)}")
    xyz = np.asarray(cloud.numpy(("x", "y", "z")), np.float64).reshape(-1, 3)
    if len(xyz) != cloud.metadata.points:
        raise ValueError(f"its header says POINTS {cloud.metadata.points}, its data holds {len(xyz)} (a cut file?)")
    return xyz


def _reason(err: Exception) -> str:
    """One line of why pypcd4 refused a file: a header field's problem (pydantic's first error), a
    header that is not text, or the error's own first line."""
    if callable(getattr(err, "errors", None)):
        first = err.errors()[0]
        return f"header {' '.join(str(k).upper() for k in first.get('loc', ()))}: {first.get('msg', err)}"
    if isinstance(err, UnicodeDecodeError):
        return "its header is not text (no DATA line before the data?)"
    return (str(err).splitlines() or [type(err).__name__])[0]
