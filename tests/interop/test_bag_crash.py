"""SIGKILL on the real recorder, then the readers users have on the recovered bag.

Run by run-bag-crash.sh (OILFILM_BIN: our binaries; OILFILM_READ_BAG: our reader, the
read_bag example). The sim exciter and DAQ publish on DDS (a domain of their own), the
`oilfilm-recorder` binary records with its default chunking (1 MiB or 1 s of log time) and
is killed with SIGKILL once three chunks are on disk. Before recovery the mcap library's
non-seeking reader gives the messages of the complete chunks; `oilfilm bag recover` then
makes the bag valid, and rosbags' AnyReader (type hash checked when present), mcap +
mcap-ros2-support and our reader must all return exactly those messages, with equal
values.
"""

import os
import signal
import subprocess
import time
from pathlib import Path

import pytest
from ruamel.yaml import YAML

from bag_values import assert_same, plain

ROOT = Path(__file__).resolve().parents[2]
BIN = Path(os.environ["OILFILM_BIN"])
READ_BAG = os.environ["OILFILM_READ_BAG"]
WORK = Path(os.environ["OILFILM_WORK"])
PARAMS = ROOT / "launch_configs" / "params" / "sim_rig.yaml"


def node_args(name, *params):
    args = ["--ros-args", "-r", f"__node:={name}", "-r", "__ns:=/oilfilm", "--params-file", str(PARAMS)]
    for p in params:
        args += ["-p", p]
    return args


def complete_chunks(path):
    """Chunks whole on disk (the mcap library's streaming reader, up to the cut)."""
    from mcap.records import Chunk
    from mcap.stream_reader import StreamReader

    chunks = 0
    try:
        with path.open("rb") as f:
            for record in StreamReader(f, emit_chunks=True, record_size_limit=None).records:
                if isinstance(record, Chunk):
                    chunks += 1
    except Exception:  # the file ends inside the chunk being written
        pass
    return chunks


@pytest.fixture(scope="module")
def killed_bag():
    env = dict(os.environ, ROS_DOMAIN_ID=os.environ.get("ROS_DOMAIN_ID", str(210 + os.getpid() % 10)), RUST_LOG="warn")
    bag = WORK / "killed"
    mcap_file = bag / "killed_0.mcap"
    log = (WORK / "nodes.log").open("w")
    recorder = subprocess.Popen([BIN / "oilfilm-recorder", *node_args("recorder", f"output:={bag}")], env=env, stdout=log, stderr=log)
    graph = [
        subprocess.Popen([BIN / "oilfilm-exciter", *node_args("exciter")], env=env, stdout=log, stderr=log),
        subprocess.Popen([BIN / "oilfilm-daq", *node_args("daq", "rate_factor:=1.0")], env=env, stdout=log, stderr=log),
    ]
    try:
        deadline = time.monotonic() + 60
        # Each topic (command, frames, status) has chunks of its own: nine complete chunks
        # are about three seconds, three chunks of DAQ frames.
        while time.monotonic() < deadline and not (mcap_file.exists() and complete_chunks(mcap_file) >= 9):
            assert recorder.poll() is None, "the recorder died by itself"
            time.sleep(0.1)
        assert complete_chunks(mcap_file) >= 9, "nine chunks not written in 60 s"
        time.sleep(0.6)  # the kill lands inside the next chunk
        recorder.send_signal(signal.SIGKILL)
        recorder.wait(timeout=10)
    finally:
        for p in graph + [recorder]:
            if p.poll() is None:
                p.send_signal(signal.SIGINT)
        for p in graph + [recorder]:
            try:
                p.wait(timeout=10)
            except subprocess.TimeoutExpired:
                p.kill()
        log.close()
    assert recorder.returncode == -signal.SIGKILL
    assert not (bag / "metadata.yaml").exists(), "a killed recorder writes no metadata.yaml"

    from mcap.exceptions import EndOfFile, McapError
    from mcap.reader import NonSeekingReader

    before = []
    with mcap_file.open("rb") as f:
        try:
            # In file order: sorting by log time would read to the cut before yielding.
            for _schema, channel, message in NonSeekingReader(f, record_size_limit=None).iter_messages(log_time_order=False):
                before.append((channel.topic, message.log_time, bytes(message.data)))
        except (McapError, EndOfFile, OverflowError):
            # The cut: everything before it was returned. A file killed by SIGKILL (not one
            # cut short by hand) ends in the chunk being written, whose record length is
            # still the writer's placeholder (all ones): the library overflows on it.
            pass
    assert len(before) > 20

    run = subprocess.run([BIN / "oilfilm", "bag", "recover", str(bag)], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    assert "rewritten from" in run.stdout, run.stdout
    return bag, before


@pytest.fixture(scope="module")
def ours(killed_bag):
    bag, _ = killed_bag
    run = subprocess.run([READ_BAG, str(bag)], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    return YAML(typ="safe").load(run.stdout)


def sorted_key(entries):
    return sorted(entries, key=lambda e: (e[1], e[0]))


def test_our_reader_holds_every_message_of_the_complete_chunks(killed_bag, ours):
    _, before = killed_bag
    assert len(ours) == len(before)
    assert sorted((m["topic"], m["log_time"]) for m in ours) == sorted((t, lt) for t, lt, _ in before)
    seqs = [m["value"]["sequence"] for m in ours if m["topic"] == "/oilfilm/daq/frames"]
    assert len(seqs) >= 20 and seqs == list(range(seqs[0], seqs[0] + len(seqs))), "frames contiguous"


def test_rosbags_anyreader_reads_the_recovered_bag(killed_bag, ours):
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    bag, before = killed_bag
    got = []
    with AnyReader([bag], default_typestore=get_typestore(Stores.EMPTY)) as reader:
        assert reader.message_count == len(before)
        for conn, t, raw in reader.messages():
            got.append((conn.topic, t, reader.deserialize(raw, conn.msgtype), bytes(raw)))
    assert sorted((t, lt, raw) for t, lt, _, raw in got) == sorted(before), "rosbags returns the complete chunks' bytes"
    want = sorted_key([(m["topic"], m["log_time"], m["value"]) for m in ours])
    for (gt, glt, gv, _), (wt, wlt, wv) in zip(sorted_key(got), want):
        assert (gt, glt) == (wt, wlt)
        assert_same(plain(gv), wv, f"{gt}@{glt}")


def test_mcap_ros2_reads_the_recovered_bag(killed_bag, ours):
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    bag, before = killed_bag
    got = []
    with (bag / "killed_0.mcap").open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        assert reader.get_header().profile == "ros2"
        assert reader.get_summary().statistics.message_count == len(before)
        for _schema, channel, message, decoded in reader.iter_decoded_messages(log_time_order=True):
            got.append((channel.topic, message.log_time, decoded))
    want = sorted_key([(m["topic"], m["log_time"], m["value"]) for m in ours])
    assert len(got) == len(want)
    for (gt, glt, gv), (wt, wlt, wv) in zip(sorted_key(got), want):
        assert (gt, glt) == (wt, wlt)
        assert_same(plain(gv), wv, f"{gt}@{glt}")
