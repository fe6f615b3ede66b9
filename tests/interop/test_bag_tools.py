"""Our bags in the ROS / MCAP tools users run, and a rosbags-written bag in `oilfilm identify`.

Run by run-bag-readers.sh beside test_bag_readers.py (same environment variables, plus
OILFILM_BAGS: extra bags of ours (lz4, uncompressed, split) separated by ':', and
OILFILM_BIN: the `oilfilm` binary).

* the RIHS01 type hashes we write equal rosbags' own computation from msgs/*.msg and (when
  setup-ros-venv.sh has built msgs/) rosidl's generator's, and rosbags' AnyReader checks
  them (and refuses a wrong one, so the check is real);
* `pymcap-cli doctor` (PyPI `pymcap-cli`) reports no error and no warning on every file of
  our bags (zstd, lz4, none, split, recovered, the committed reference bag), and does report
  a corrupted chunk;
* `rosbags-convert` turns our bag into a sqlite3 bag and back into MCAP with byte-identical
  payloads, topics, types and log times;
* a bag written by rosbags' Writer (types registered from msgs/) is read by the real
  `oilfilm identify BAG --replay --json`, whose estimates equal those the node graph
  published live.
"""

import json
import math
import os
import shutil
import subprocess
from pathlib import Path

import pytest
from ruamel.yaml import YAML

from test_bag_readers import BAG, ROOT, build, load_expected

BIN = os.environ["OILFILM_BIN"]
EXTRA_BAGS = [Path(p) for p in os.environ.get("OILFILM_BAGS", "").split(":") if p]
REFERENCE = ROOT / "bags" / "sim_rig_multisine"


def tool(name):
    """A console script of the test venv (next to this interpreter)."""
    import sys

    path = Path(sys.executable).parent / name
    assert path.exists(), f"{path}: not installed by setup-bag-venv.sh"
    return str(path)


@pytest.fixture(scope="module")
def expected():
    return load_expected()


def our_typestore():
    """rosbags' typestore with our .msg files registered (std_msgs, builtin_interfaces from
    rosbags' own jazzy store)."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    ts = get_typestore(Stores.ROS2_JAZZY)
    types = {}
    for p in sorted((ROOT / "msgs" / "msg").glob("*.msg")):
        types.update(get_types_from_msg(p.read_text(), f"oilfilm_msgs/msg/{p.stem}"))
    ts.register(types)
    return ts


def metadata(bag):
    return YAML(typ="safe").load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]


def raw_messages(bag):
    """(topic, type, log_time, payload bytes) of every message of a bag's MCAP files, by
    the mcap library (no decoding), sorted by log time then topic."""
    from mcap.reader import make_reader

    out = []
    for f in sorted(bag.glob("*.mcap")):
        with f.open("rb") as fh:
            for schema, channel, message in make_reader(fh).iter_messages(log_time_order=True):
                out.append((channel.topic, schema.name, message.log_time, bytes(message.data)))
    return sorted(out, key=lambda m: (m[2], m[0]))


# --- RIHS01 type hashes -------------------------------------------------------------


def test_type_hashes_are_rosbags_own_and_anyreader_checks_them(tmp_path):
    from mcap.reader import make_reader
    from rosbags.highlevel import AnyReader, AnyReaderError
    from rosbags.typesys import Stores, get_typestore

    ts = our_typestore()
    topics = metadata(BAG)["topics_with_message_count"]
    assert len(topics) == 6
    for t in topics:
        m = t["topic_metadata"]
        assert m["type_description_hash"].startswith("RIHS01_"), m
        assert m["type_description_hash"] == ts.hash_rihs01(m["type"]), m["type"]
    with (BAG / f"{BAG.name}_0.mcap").open("rb") as f:
        summary = make_reader(f).get_summary()
    for c in summary.channels.values():
        schema = summary.schemas[c.schema_id]
        assert c.metadata.get("topic_type_hash") == ts.hash_rihs01(schema.name), c.topic

    # AnyReader takes the hashes from metadata.yaml and compares each with its own hash of
    # the schema in the MCAP file: ours pass.
    with AnyReader([BAG], default_typestore=get_typestore(Stores.EMPTY)) as reader:
        digests = {c.msgtype: c.digest for c in reader.connections}
        assert set(digests) == {t["topic_metadata"]["type"] for t in topics}
        for msgtype, digest in digests.items():
            assert digest == ts.hash_rihs01(msgtype) == reader.typestore.hash_rihs01(msgtype)
        assert sum(1 for _ in reader.messages()) == metadata(BAG)["message_count"]

    # A wrong hash (one hex digit changed) is refused: the check is real.
    bad = tmp_path / BAG.name
    shutil.copytree(BAG, bad)
    text = (bad / "metadata.yaml").read_text()
    h = ts.hash_rihs01("oilfilm_msgs/msg/DaqFrame")
    wrong = h[:-1] + ("0" if h[-1] != "0" else "1")
    (bad / "metadata.yaml").write_text(text.replace(h, wrong))
    with pytest.raises(AnyReaderError, match="DaqFrame.*hash mismatch"):
        with AnyReader([bad], default_typestore=get_typestore(Stores.EMPTY)):
            pass


def test_type_hashes_equal_rosidls_when_its_build_is_there():
    """rosidl's own generator wrote the hashes into the interface package that
    setup-ros-venv.sh builds (run-all.sh builds it before this test): ours must equal them."""
    share = ROOT / "target" / "ros" / "oilfilm_msgs" / "share" / "oilfilm_msgs" / "msg"
    if not share.is_dir():
        pytest.skip(f"{share}: no rosidl build (bash tests/interop/setup-ros-venv.sh makes one)")
    rosidl = {}
    for f in share.glob("*.json"):
        for h in json.loads(f.read_text())["type_hashes"]:
            rosidl[h["type_name"]] = h["hash_string"]
    ours = {t["topic_metadata"]["type"]: t["topic_metadata"]["type_description_hash"] for t in metadata(BAG)["topics_with_message_count"]}
    assert len(ours) == 5
    for ty, h in ours.items():
        assert rosidl.get(ty) == h, f"{ty}: ours {h}, rosidl {rosidl.get(ty)}"


# --- pymcap-cli doctor --------------------------------------------------------------


def doctor(path):
    run = subprocess.run([tool("pymcap-cli"), "doctor", "--format", "jsonl", str(path)], capture_output=True, text=True)
    lines = [json.loads(x) for x in run.stdout.splitlines() if x.strip().startswith("{")]
    summary = [x for x in lines if x.get("type") == "summary"]
    assert len(summary) == 1, run.stdout + run.stderr
    findings = [x for x in lines if x.get("type") == "finding" and x.get("severity") in ("error", "warning")]
    return run.returncode, summary[0], findings


def killed_and_recovered(tmp_path):
    """A copy of the test bag cut mid-chunk without metadata.yaml, recovered by ours."""
    from mcap.reader import make_reader

    bag = tmp_path / "recovered"
    bag.mkdir()
    src = BAG / f"{BAG.name}_0.mcap"
    with src.open("rb") as f:
        chunks = make_reader(f).get_summary().chunk_indexes
    k = len(chunks) // 2
    cut = chunks[k].chunk_start_offset + chunks[k].chunk_length // 2
    (bag / "recovered_0.mcap").write_bytes(src.read_bytes()[:cut])
    run = subprocess.run([BIN, "bag", "recover", str(bag)], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    return bag


def test_pymcap_cli_doctor_finds_no_error_in_our_bags(tmp_path):
    bags = [BAG, REFERENCE, *EXTRA_BAGS, killed_and_recovered(tmp_path)]
    files = [f for b in bags for f in sorted(b.glob("*.mcap"))]
    assert len(files) >= len(bags) + 1, "the split bag holds several files"
    for f in files:
        rc, summary, findings = doctor(f)
        assert rc == 0 and summary["errors"] == 0 and summary["warnings"] == 0, f"{f}: {findings}"
        assert summary["complete"] and summary["messages"] > 0, summary

    # The doctor does find damage: a byte flipped inside a chunk is a CRC error.
    bad = tmp_path / "bad.mcap"
    data = bytearray((BAG / f"{BAG.name}_0.mcap").read_bytes())
    from mcap.reader import make_reader

    with (BAG / f"{BAG.name}_0.mcap").open("rb") as fh:
        chunk = make_reader(fh).get_summary().chunk_indexes[0]
    data[chunk.chunk_start_offset + chunk.chunk_length - 10] ^= 0x55
    bad.write_bytes(bytes(data))
    rc, summary, findings = doctor(bad)
    assert rc != 0 and summary["errors"] >= 1, summary
    assert any("CRC" in x["code"] for x in findings), findings


# --- rosbags-convert ------------------------------------------------------------------


def test_rosbags_convert_round_trips_to_sqlite3_and_back_byte_identical(tmp_path):
    from rosbags.rosbag2 import Reader

    sqlite = tmp_path / "as_sqlite3"
    back = tmp_path / "back_to_mcap"
    for src, dst, storage in [(BAG, sqlite, "sqlite3"), (sqlite, back, "mcap")]:
        run = subprocess.run([tool("rosbags-convert"), "--src", str(src), "--dst", str(dst), "--dst-storage", storage], capture_output=True, text=True)
        assert run.returncode == 0, run.stdout + run.stderr
    assert metadata(sqlite)["storage_identifier"] == "sqlite3" and list(sqlite.glob("*.db3"))
    assert metadata(back)["storage_identifier"] == "mcap"

    ours = raw_messages(BAG)
    assert len(ours) == metadata(BAG)["message_count"]
    # The sqlite3 bag holds the same payloads...
    with Reader(sqlite) as r:
        types = {c.topic: c.msgtype for c in r.connections}
        mid = sorted(((c.topic, c.msgtype, t, bytes(raw)) for c, t, raw in r.messages()), key=lambda m: (m[2], m[0]))
    assert [(t, ty) for t, ty, _, _ in mid] == [(t, ty) for t, ty, _, _ in ours]
    assert mid == ours, "payloads changed on the way to sqlite3"
    # ...and so does the MCAP bag converted back, byte for byte.
    again = raw_messages(back)
    assert len(again) == len(ours)
    for i, (a, b) in enumerate(zip(again, ours)):
        assert a[:3] == b[:3], f"message {i}: {a[:3]} != {b[:3]}"
        assert a[3] == b[3], f"message {i} on {a[0]}: payload bytes differ"
    assert set(types.values()) == {t[1] for t in ours}
    # Our reader reads the converted bag too.
    run = subprocess.run([os.environ["OILFILM_READ_BAG"], str(back)], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    assert len(YAML(typ="safe").load(run.stdout)) == len(ours)


# --- oilfilm identify on a rosbags-written bag -----------------------------------------


def same_value(got, want, path):
    """JSON (serde_json writes NaN as null) against the YAML of what was published."""
    if isinstance(want, float) and math.isnan(want):
        assert got is None, f"{path}: {got!r} is not NaN/null"
    elif isinstance(want, float):
        assert isinstance(got, (int, float)) and float(got) == want, f"{path}: {got!r} != {want!r}"
    elif isinstance(want, list):
        assert isinstance(got, list) and len(got) == len(want), f"{path}: {got!r} != {want!r}"
        for i, (g, w) in enumerate(zip(got, want)):
            same_value(g, w, f"{path}[{i}]")
    elif isinstance(want, dict):
        for k, w in want.items():
            same_value(got[k], w, f"{path}.{k}")
    else:
        assert got == want, f"{path}: {got!r} != {want!r}"


def test_oilfilm_identify_reads_a_bag_written_by_rosbags(expected, tmp_path):
    from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime
    from rosbags.rosbag2 import StoragePlugin, Writer

    ts = our_typestore()
    inf = QosTime(9223372036, 854775807)
    qos = Qos(QosHistory.KEEP_LAST, 10, QosReliability.RELIABLE, QosDurability.VOLATILE, inf, inf, QosLiveliness.AUTOMATIC, inf, False)
    out = tmp_path / "rosbags_written"
    inputs = [m for m in expected if m["topic"] in ("/oilfilm/daq/frames", "/oilfilm/rig/status")]
    with Writer(out, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        conns = {}
        for m in inputs:
            if m["topic"] not in conns:
                conns[m["topic"]] = w.add_connection(m["topic"], m["type"], typestore=ts, offered_qos_profiles=[qos])
            w.write(conns[m["topic"]], m["log_time"], ts.serialize_cdr(build(ts, m["type"], m["value"]), m["type"]))
    # The short run's settings (GraphParams::sim_rig(2 s, 5000, 2500): the sim_rig launch
    # file, ADR 0021): its params file, causal chain included, with 1 s windows every 0.5 s.
    # rosbags' bag holds no conditioned frames, so identify takes the chain from the file.
    params = ROOT / "launch_configs" / "params" / "sim_rig.yaml"
    assert "chain: causal" in params.read_text()
    run = subprocess.run([BIN, "identify", str(out), "--replay", "--params", str(params), "--window", "5000", "--hop", "2500", "--json"], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    doc = json.loads(run.stdout)
    assert doc["frames"] == sum(1 for m in inputs if m["topic"] == "/oilfilm/daq/frames")
    live = [m["value"] for m in expected if m["topic"] == "/oilfilm/estimates"]
    assert live and all(e["solved"] for e in live), "the 2 s run gives one solved 1 s window"
    assert len(doc["estimates"]) == len(live)
    for i, (got, want) in enumerate(zip(doc["estimates"], live)):
        same_value(got, want, f"estimates[{i}]")
    solved = [e for e in doc["estimates"] if e["solved"]]
    assert solved and all(e["stiffness_n_m"][0] > 0 and e["damping_n_s_m"][3] > 0 for e in solved)
