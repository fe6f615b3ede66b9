"""Records written by the libraries labs use, read by `oilfilm import` and `oilfilm identify`.

One simulated record (`oilfilm simulate`, our ASCII format) is written again the way a lab
would hold it:

* TDMS by npTDMS, the probes, frame probes, forces and thermocouple in four groups plus a
  group the map does not name, over several segments with the sample interval and start time
  as waveform properties; and an interleaved TDMS file (DAQmx logging writes interleaved raw
  data; npTDMS does not write it, so this test writes it by the TDMS specification and checks
  that npTDMS reads it back to the record);
* a MATLAB MAT-file by scipy.io.savemat holding a struct of channels and the sample rate;
* a CSV by pandas with a units row under the header and a time column.

Each is imported to a bag through its channel map and identified; the coefficients equal,
bit for bit, those of the ASCII record imported the same way (every writer keeps a float's
bits: TDMS and MAT as binary doubles, pandas with the shortest round-trip repr). A CSV that
pandas wrote with a comma decimal separator is refused with a message saying so, and no bag
is written.

    OILFILM_BIN=target/debug/oilfilm .venv-foreign/bin/python -m pytest tests/interop/test_foreign_files.py
"""

import json
import os
import struct
import subprocess
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import scipy.io
from nptdms import ChannelObject, GroupObject, RootObject, TdmsFile, TdmsWriter

BIN = os.environ["OILFILM_BIN"]
RATE_HZ = 5000.0
# 2 s windows every second.
WINDOW = ["--window", "10000", "--hop", "5000"]

# The rig's channels (the simulated record's scan order) and where a lab keeps each.
CHANNELS = [
    ("probe_a_x", "Bearing probes", "A horizontal"),
    ("probe_a_y", "Bearing probes", "A vertical"),
    ("probe_b_x", "Bearing probes", "B horizontal"),
    ("probe_b_y", "Bearing probes", "B vertical"),
    ("frame_x", "Housing probes", "x"),
    ("frame_y", "Housing probes", "y"),
    ("f1", "Exciters", "Shaker 1"),
    ("f2", "Exciters", "Shaker 2"),
    ("f3", "Exciters", "Static load"),
    ("temperature", "Thermal", "Bearing TC"),
]


def oilfilm(*args, check=True):
    out = subprocess.run([BIN, *map(str, args)], capture_output=True, text=True)
    if check and out.returncode != 0:
        raise AssertionError(f"oilfilm {' '.join(map(str, args))}:\n{out.stderr}")
    return out


@pytest.fixture(scope="module")
def record(tmp_path_factory):
    """The simulated record: its path and its columns (volts, as the card gave them)."""
    d = tmp_path_factory.mktemp("record")
    path = d / "record.txt"
    oilfilm("simulate", "--seconds", "6", "-o", path)
    lines = path.read_text().splitlines()
    header = next(line for line in lines if not line.startswith("#"))
    names = header.split()[1:]
    assert names == [c[0] for c in CHANNELS], names
    data = np.loadtxt(path, comments="#", skiprows=lines.index(header) + 1)
    # Python's float() reads each printed value to the double the Rust reader gets.
    return path, {name: data[:, k + 1].copy() for k, name in enumerate(names)}


def map_text(froms, timing, extra=""):
    text = f'{extra}\n[timing]\n{timing}\nmultiplexer = "sequential"\nchannel_interval_s = 1e-5\n\n'
    for (rig, _, _), source in zip(CHANNELS, froms):
        text += f'[[channel]]\nrig = "{rig}"\n{source}\nunit = "V"\n\n'
    return text


def coefficients(doc):
    """Each window's solved coefficients (or refusal) from `identify --json`."""
    windows = doc["windows"]
    assert windows, doc
    return [w["estimate"]["result"] for w in windows]


def import_and_identify(tmp_path, record_path, map_text_=None):
    bag = tmp_path / f"{Path(record_path).stem}-bag"
    args = ["import", record_path, "-o", bag]
    if map_text_ is not None:
        m = tmp_path / f"{Path(record_path).stem}.map.toml"
        m.write_text(map_text_)
        args += ["--map", m]
    oilfilm(*args)
    return json.loads(oilfilm("identify", bag, *WINDOW, "--json").stdout)


@pytest.fixture(scope="module")
def reference(record, tmp_path_factory):
    path, _ = record
    doc = import_and_identify(tmp_path_factory.mktemp("ascii"), path)
    solved = [r for r in coefficients(doc) if "Ok" in r]
    assert len(solved) >= 3, doc
    # The bag holds the record as the ASCII file does: identifying either gives the same.
    direct = json.loads(oilfilm("identify", path, *WINDOW, "--json").stdout)
    assert coefficients(direct) == coefficients(doc)
    return coefficients(doc)


def test_nptdms_groups_over_segments(record, reference, tmp_path):
    _, cols = record
    path = tmp_path / "lab.tdms"
    start = np.datetime64("2026-03-04T09:30:00", "us")  # UTC, as LabVIEW stores it
    wf = {"wf_increment": 1.0 / RATE_HZ, "wf_start_time": start, "wf_start_offset": 0.0, "unit_string": "V"}
    with TdmsWriter(path) as w:
        # LabVIEW's logging loop writes a segment per read of the card.
        n = len(cols["probe_a_x"])
        for k, lo in enumerate(range(0, n, 7000)):
            hi = min(lo + 7000, n)
            objects = [RootObject({"operator": "lab", "speed_rpm": 1500.0})] if k == 0 else []
            objects += [GroupObject(g) for g in dict.fromkeys(c[1] for c in CHANNELS)] if k == 0 else []
            objects += [ChannelObject(g, name, cols[rig][lo:hi], properties=wf if k == 0 else {}) for rig, g, name in CHANNELS]
            # A channel the map does not name, in a group of its own.
            objects.append(ChannelObject("Accelerometers", "Pedestal", np.zeros(hi - lo)))
            w.write_segment(objects)
    back = TdmsFile.read(path)
    assert np.array_equal(back["Bearing probes"]["A horizontal"][:], cols["probe_a_x"])
    m = map_text([f'from = "{g}/{name}"' for _, g, name in CHANNELS], 'sample_rate_from = "wf_increment"', 'format = "tdms"\n[speed]\nproperty = "speed_rpm"')
    assert coefficients(import_and_identify(tmp_path, path, m)) == reference


def tdms_interleaved(path, columns, segments):
    """A TDMS file whose raw data is interleaved (value 0 of every channel, then value 1, ...),
    as NI-DAQmx logging writes it, in `segments` segments, written by the TDMS file format
    specification: lead-in (tag, ToC, version, offsets), metadata (objects, raw data index,
    properties), raw data."""

    def string(s):
        b = s.encode()
        return struct.pack("<I", len(b)) + b

    def prop_double(name, value):
        return string(name) + struct.pack("<Id", 10, value)

    names = list(columns)
    n = len(columns[names[0]])
    bounds = np.linspace(0, n, segments + 1).astype(int)
    with open(path, "wb") as f:
        for k in range(segments):
            lo, hi = bounds[k], bounds[k + 1]
            objects = [string("/") + struct.pack("<II", 0xFFFFFFFF, 0)] if k == 0 else []
            for group, channel in names:
                index = struct.pack("<IIIQ", 20, 10, 1, hi - lo)  # length, tdsTypeDoubleFloat, dimension, count
                props = [prop_double("wf_increment", 1.0 / RATE_HZ)] if k == 0 else []
                objects.append(string(f"/'{group}'/'{channel}'") + index + struct.pack("<I", len(props)) + b"".join(props))
            meta = struct.pack("<I", len(objects)) + b"".join(objects)
            raw = np.column_stack([columns[c][lo:hi] for c in names]).astype("<f8").tobytes()
            toc = (1 << 1) | (1 << 2) | (1 << 3) | (1 << 5)  # metadata, new object list, raw data, interleaved
            f.write(b"TDSm" + struct.pack("<IIQQ", toc, 4713, len(meta) + len(raw), len(meta)) + meta + raw)


def test_interleaved_tdms(record, reference, tmp_path):
    _, cols = record
    path = tmp_path / "daqmx.tdms"
    columns = {(g, name): cols[rig] for rig, g, name in CHANNELS}
    tdms_interleaved(path, columns, segments=5)
    back = TdmsFile.read(path)
    for rig, g, name in CHANNELS:
        assert np.array_equal(back[g][name][:], cols[rig]), f"npTDMS reads {g}/{name} back"
    m = map_text([f'from = "{g}/{name}"' for _, g, name in CHANNELS], 'sample_rate_from = "wf_increment"', "[speed]\nrpm = 1500")
    assert coefficients(import_and_identify(tmp_path, path, m)) == reference


def test_scipy_mat_struct(record, reference, tmp_path):
    _, cols = record
    path = tmp_path / "run.mat"
    run = {rig: cols[rig] for rig, _, _ in CHANNELS}
    run["fs"] = RATE_HZ
    run["rpm"] = 1500.0
    # A dict is saved as a 1x1 struct; 1-D arrays as column vectors, as MATLAB users keep
    # channels (the reader takes rows too).
    scipy.io.savemat(path, {"run": run, "note": "journal bearing, 1500 rpm"}, do_compression=True, oned_as="column")
    back = scipy.io.loadmat(path, squeeze_me=True)
    assert np.array_equal(back["run"]["probe_a_x"].item(), cols["probe_a_x"])
    m = map_text([f'from = "run.{rig}"' for rig, _, _ in CHANNELS], 'sample_rate_from = "run.fs"', '[speed]\nproperty = "run.rpm"')
    assert coefficients(import_and_identify(tmp_path, path, m)) == reference


def test_pandas_csv_with_a_units_row(record, reference, tmp_path):
    _, cols = record
    path = tmp_path / "export.csv"
    n = len(cols["probe_a_x"])
    frame = {("Time", "s"): np.arange(n) / RATE_HZ}
    frame.update({(f"{g} {name}", "V"): cols[rig] for rig, g, name in CHANNELS})
    # Two header rows: names, then units.
    pd.DataFrame(frame).to_csv(path, index=False)
    text = path.read_text().splitlines()
    assert text[0].startswith("Time,") and text[1].startswith("s,V"), text[:2]
    back = pd.read_csv(path, header=[0, 1])
    assert np.array_equal(back[("Bearing probes A horizontal", "V")].to_numpy(), cols["probe_a_x"])
    m = map_text([f'from = "{g} {name}"' for _, g, name in CHANNELS], "sample_rate_hz = 5000", "[csv]\nunits_row = true\n[speed]\nrpm = 1500")
    assert coefficients(import_and_identify(tmp_path, path, m)) == reference


def test_a_comma_decimal_csv_is_refused_and_nothing_written(record, tmp_path):
    _, cols = record
    path = tmp_path / "excel.csv"
    pd.DataFrame({f"{g} {name}": cols[rig][:2000] for rig, g, name in CHANNELS}).to_csv(path, index=False, sep=";", decimal=",")
    assert "," in path.read_text().splitlines()[1]
    m = tmp_path / "excel.map.toml"
    m.write_text(map_text([f'from = "{g} {name}"' for _, g, name in CHANNELS], "sample_rate_hz = 5000", '[csv]\ndelimiter = ";"'))
    bag = tmp_path / "excel-bag"
    out = oilfilm("import", path, "--map", m, "-o", bag, check=False)
    assert out.returncode != 0
    assert "excel.csv" in out.stderr and "line 2" in out.stderr and "comma as its decimal separator" in out.stderr, out.stderr
    assert not bag.exists()
    assert not [p for p in tmp_path.iterdir() if "importing" in p.name], list(tmp_path.iterdir())
