"""Decoded ROS message values as plain Python data, and their comparison: shared by the bag
interop tests (rosbags dataclasses, mcap_ros2 dynamic messages, numpy arrays, bytes)."""

import math

import numpy as np


def plain(v):
    """A decoded value (rosbags dataclass, mcap_ros2 dynamic message, numpy array, bytes)
    as plain Python data."""
    if isinstance(v, np.ndarray):
        return [plain(x) for x in v.tolist()]
    if isinstance(v, (bytes, bytearray)):
        return list(v)
    if isinstance(v, (list, tuple)):
        return [plain(x) for x in v]
    if isinstance(v, np.generic):
        return v.item()
    if isinstance(v, (bool, int, float, str)) or v is None:
        return v
    if isinstance(v, dict):
        return {k: plain(x) for k, x in v.items()}
    slots = getattr(v, "__slots__", None) or list(getattr(v, "__dataclass_fields__", {}))
    return {k: plain(getattr(v, k)) for k in slots if not k.startswith("_") and k != "__msgtype__"}


def assert_same(got, want, path="msg"):
    if isinstance(want, dict):
        assert isinstance(got, dict), f"{path}: {got!r} is not a message"
        assert set(want) <= set(got), f"{path}: fields {set(want) - set(got)} missing"
        for k, w in want.items():
            assert_same(got[k], w, f"{path}.{k}")
    elif isinstance(want, list):
        assert isinstance(got, list) and len(got) == len(want), f"{path}: length {len(got) if isinstance(got, list) else got!r} != {len(want)}"
        for i, (g, w) in enumerate(zip(got, want)):
            assert_same(g, w, f"{path}[{i}]")
    elif isinstance(want, float):
        assert isinstance(got, float), f"{path}: {got!r} is not a float"
        assert got == want or (math.isnan(got) and math.isnan(want)), f"{path}: {got!r} != {want!r}"
    elif isinstance(want, bool):
        assert got is want or got == int(want), f"{path}: {got!r} != {want!r}"
    else:
        assert got == want, f"{path}: {got!r} != {want!r}"
