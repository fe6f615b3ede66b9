"""Our rosbag2 MCAP bags in the readers users have, and a rosbags-written bag in ours.

Run by run-bag-readers.sh, which writes a bag of a short sim_rig run with our writer
(OILFILM_BAG) and what every message held (OILFILM_EXPECTED, YAML: it carries NaN) and
points OILFILM_READ_BAG at our reader (the read_bag example).

* rosbags' AnyReader (types from the bag's own schemas) decodes every message, values
  equal to what was published;
* mcap + mcap-ros2-support (the Foxglove Python stack) likewise, in log-time order;
* rosbags' writer, with our .msg files, writes the same messages; our reader returns them
  with equal values.
"""

import functools
import os
import subprocess
from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest
from ruamel.yaml import YAML

from bag_values import assert_same, plain

ROOT = Path(__file__).resolve().parents[2]
BAG = Path(os.environ["OILFILM_BAG"])
EXPECTED = Path(os.environ["OILFILM_EXPECTED"])
READ_BAG = os.environ["OILFILM_READ_BAG"]


@functools.cache
def load_expected():
    """What every message held (parsed once per session: the YAML takes seconds)."""
    msgs = YAML(typ="safe").load(EXPECTED.read_text())
    assert len(msgs) > 20
    return msgs


@pytest.fixture(scope="module")
def expected():
    return load_expected()


def by_topic(entries):
    out = defaultdict(list)
    for topic, log_time, value in entries:
        out[topic].append((log_time, value))
    return dict(out)


def check_all(got_entries, expected):
    got = by_topic(got_entries)
    want = by_topic((m["topic"], m["log_time"], m["value"]) for m in expected)
    assert set(got) == set(want), f"topics {sorted(got)} != {sorted(want)}"
    for topic, msgs in want.items():
        g = got[topic]
        assert len(g) == len(msgs), f"{topic}: {len(g)} messages, published {len(msgs)}"
        for i, ((gt, gv), (wt, wv)) in enumerate(zip(g, msgs)):
            assert gt == wt, f"{topic}[{i}]: log time {gt} != {wt}"
            assert_same(plain(gv), wv, f"{topic}[{i}]")


def test_rosbags_anyreader_decodes_every_message(expected):
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    with AnyReader([BAG], default_typestore=get_typestore(Stores.EMPTY)) as reader:
        assert reader.message_count == len(expected)
        types = {c.topic: c.msgtype for c in reader.connections}
        assert types["/oilfilm/daq/frames"] == "oilfilm_msgs/msg/DaqFrame"
        qos = {c.topic: c.ext.offered_qos_profiles for c in reader.connections}
        assert qos["/oilfilm/rig/status"][0].depth == 10
        # Only exciter/command keeps history for late joiners (ADR 0025).
        assert qos["/oilfilm/rig/status"][0].durability.name == "VOLATILE"
        assert qos["/oilfilm/exciter/command"][0].durability.name == "TRANSIENT_LOCAL"
        entries = []
        last = 0
        for conn, t, raw in reader.messages():
            assert t >= last, "AnyReader yields in log-time order"
            last = t
            entries.append((conn.topic, t, reader.deserialize(raw, conn.msgtype)))
    check_all(entries, expected)


def test_mcap_ros2_decodes_every_message(expected):
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    entries = []
    with (BAG / f"{BAG.name}_0.mcap").open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        assert reader.get_header().profile == "ros2"
        summary = reader.get_summary()
        assert summary.statistics.message_count == len(expected)
        assert all(c.metadata.get("offered_qos_profiles") for c in summary.channels.values())
        assert {s.encoding for s in summary.schemas.values()} == {"ros2msg"}
        for schema, channel, message, decoded in reader.iter_decoded_messages(log_time_order=True):
            assert channel.message_encoding == "cdr"
            entries.append((channel.topic, message.log_time, decoded))
    check_all(entries, expected)


def build(ts, msgtype, value):
    """A rosbags message of `msgtype` from plain data, typed by the typestore's field table."""
    fields = ts.fielddefs[msgtype][1]
    kwargs = {}
    for name, desc in fields:
        kwargs[name] = build_field(ts, desc, value[name])
    return ts.types[msgtype](**kwargs)


def build_field(ts, desc, v):
    kind, arg = desc
    if kind.name == "NAME":
        return build(ts, arg, v)
    if kind.name == "BASE":
        return v
    inner, _n = arg
    if inner[0].name == "BASE" and inner[1][0] not in ("string", "wstring"):
        dtype = {"float64": np.float64, "float32": np.float32, "uint8": np.uint8, "int8": np.int8, "bool": np.bool_,
                 "uint16": np.uint16, "int16": np.int16, "uint32": np.uint32, "int32": np.int32,
                 "uint64": np.uint64, "int64": np.int64}[inner[1][0]]
        return np.array(v, dtype=dtype)
    return [build_field(ts, inner, x) for x in v]


def test_our_reader_reads_a_rosbags_written_bag(expected, tmp_path):
    from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore, get_types_from_msg

    ts = get_typestore(Stores.ROS2_JAZZY)
    types = {}
    for p in sorted((ROOT / "msgs" / "msg").glob("*.msg")):
        types.update(get_types_from_msg(p.read_text(), f"oilfilm_msgs/msg/{p.stem}"))
    ts.register(types)
    inf = QosTime(9223372036, 854775807)
    qos = Qos(QosHistory.KEEP_LAST, 10, QosReliability.RELIABLE, QosDurability.VOLATILE, inf, inf, QosLiveliness.AUTOMATIC, inf, False)
    out = tmp_path / "from_rosbags"
    with Writer(out, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        conns = {}
        for m in expected:
            if m["topic"] not in conns:
                conns[m["topic"]] = w.add_connection(m["topic"], m["type"], typestore=ts, offered_qos_profiles=[qos])
            msg = build(ts, m["type"], m["value"])
            w.write(conns[m["topic"]], m["log_time"], ts.serialize_cdr(msg, m["type"]))
    run = subprocess.run([READ_BAG, str(out)], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    ours = YAML(typ="safe").load(run.stdout)
    assert len(ours) == len(expected)
    for m in ours:
        assert m["type"].startswith("oilfilm_msgs/msg/")
    check_all([(m["topic"], m["log_time"], m["value"]) for m in ours], expected)


def test_a_killed_bag_recovered_by_ours_opens_in_rosbags_and_mcap(expected, tmp_path):
    """The writer killed mid-chunk (file cut half-way through a chunk, no metadata.yaml):
    rosbags cannot open it; after our recovery both readers get exactly the messages of the
    complete chunks (as the mcap library's non-seeking reader finds them in the cut file)."""
    import shutil

    from mcap.exceptions import EndOfFile, McapError
    from mcap.reader import NonSeekingReader, make_reader
    from mcap_ros2.decoder import DecoderFactory
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    bag = tmp_path / "killed"
    shutil.copytree(BAG, bag)
    src = bag / f"{BAG.name}_0.mcap"
    mcap_file = bag / "killed_0.mcap"
    src.rename(mcap_file)
    (bag / "metadata.yaml").unlink()
    with mcap_file.open("rb") as f:
        chunks = make_reader(f).get_summary().chunk_indexes
    assert len(chunks) >= 2, "the 1 s chunk limit gives a 2.4 s run several chunks"
    k = len(chunks) // 2
    cut = chunks[k].chunk_start_offset + chunks[k].chunk_length // 2
    data = mcap_file.read_bytes()[:cut]
    mcap_file.write_bytes(data)

    with pytest.raises(Exception):
        with AnyReader([bag], default_typestore=get_typestore(Stores.EMPTY)) as r:
            list(r.messages())

    kept = []
    with mcap_file.open("rb") as f:
        try:
            for _s, channel, message in NonSeekingReader(f, record_size_limit=None).iter_messages(log_time_order=False):
                kept.append((channel.topic, message.log_time))
        except (McapError, EndOfFile):
            pass  # the cut: what came before it is the complete chunks' messages
    assert 0 < len(kept) < len(expected)

    run = subprocess.run([READ_BAG.replace("read_bag", "recover_bag"), str(bag)], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    assert f"{len(kept)} messages" in run.stdout, run.stdout

    want = [m for m in expected if (m["topic"], m["log_time"]) in set(kept)]
    assert len(want) == len(kept)
    with AnyReader([bag], default_typestore=get_typestore(Stores.EMPTY)) as reader:
        entries = [(c.topic, t, reader.deserialize(raw, c.msgtype)) for c, t, raw in reader.messages()]
    check_all(entries, want)
    entries = []
    with mcap_file.open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        assert reader.get_summary().statistics.message_count == len(kept)
        for _s, channel, message, decoded in reader.iter_decoded_messages(log_time_order=True):
            entries.append((channel.topic, message.log_time, decoded))
    check_all(entries, want)
