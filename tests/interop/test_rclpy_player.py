#!/usr/bin/env python3
"""`oilfilm play` seen from rclpy (rmw_fastrtps, loopback).

A bag of a short sim_rig run (written by the bag crate's write_sim_rig example, with
BAG.expected.yaml listing every message) is played at twice real time. An rclpy node started
with use_sim_time=true checks that:

1. /clock is offered as rosgraph_msgs/msg/Clock (not ros2-client's builtin_interfaces/Time),
   and what it carries is the bag's log time: never backwards, ending at the bag's last log
   time, and the node's own clock (rclpy's TimeSource) follows it there;
2. every topic's messages arrive, all of them, in order, with the recorded values and the
   recorded header stamps (replayed messages keep the stamps of the run);
3. one of our nodes (an estimator, in a namespace of its own so that it adds nothing to the
   played topics) started with `-p use_sim_time:=true` follows /clock too: a parameter set on
   it after the play is announced on /parameter_events and logged on /rosout stamped with
   the bag's last log time, not the wall clock's.

Run through run-rclpy-player.sh.
"""
import math
import os
import signal
import subprocess
import sys
import time

import rclpy
import yaml
from rclpy.parameter import Parameter
from rcl_interfaces.msg import Log, ParameterEvent, ParameterType, ParameterValue
from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.srv import SetParameters
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock

from oilfilm_msgs.msg import CoefficientEstimate, ConditionedFrame, DaqFrame, ExciterCommand, RigStatus

TYPES = {
    "oilfilm_msgs/msg/ExciterCommand": ExciterCommand,
    "oilfilm_msgs/msg/DaqFrame": DaqFrame,
    "oilfilm_msgs/msg/ConditionedFrame": ConditionedFrame,
    "oilfilm_msgs/msg/CoefficientEstimate": CoefficientEstimate,
    "oilfilm_msgs/msg/RigStatus": RigStatus,
}

failures = []
# Our node that follows /clock (3.), away from the played topics' namespace.
FOLLOWER_NS = "/oilfilm_sim_time"
FOLLOWER = "estimator"


def check(cond, what):
    print(("ok: " if cond else "FAIL: ") + what, file=sys.stdout if cond else sys.stderr)
    if not cond:
        failures.append(what)
    return cond


def ns(t):
    return t.sec * 1_000_000_000 + t.nanosec


def same(a, b):
    return a == b or (isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b))


def main():
    bin_dir, bag = sys.argv[1], sys.argv[2]
    with open(bag + ".expected.yaml") as f:
        expected = yaml.safe_load(f)
    topics = {}
    for m in expected:
        topics.setdefault(m["topic"], (m["type"], []))[1].append(m)
    last_log = max(m["log_time"] for m in expected)

    rclpy.init()
    node = rclpy.create_node("oilfilm_player_probe", parameter_overrides=[Parameter("use_sim_time", Parameter.Type.BOOL, True)])
    executor = rclpy.executors.SingleThreadedExecutor()
    executor.add_node(node)
    clocks, got = [], {t: [] for t in topics}
    node.create_subscription(Clock, "/clock", lambda m: clocks.append(ns(m.clock)),
                             QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE))
    qos = QoSProfile(depth=1000, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.VOLATILE)
    for t, (ty, _) in topics.items():
        node.create_subscription(TYPES[ty], t, lambda m, t=t: got[t].append(m), qos)
    # 3. Our estimator with use_sim_time, and what it says about its time.
    follower_name = f"{FOLLOWER_NS}/{FOLLOWER}"
    events, logs = [], []
    # Volatile: a transient-local reader would be incompatible with rclpy's own (volatile)
    # /parameter_events writer, and rmw would warn of it.
    node.create_subscription(ParameterEvent, "/parameter_events", lambda m: events.append(m) if m.node == follower_name else None,
                             QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE))
    node.create_subscription(Log, "/rosout", lambda m: logs.append(m) if m.name.endswith(FOLLOWER) else None,
                             QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL))
    follower_log = open(os.path.join(os.path.dirname(bag), "follower.log"), "w")
    follower = subprocess.Popen([os.path.join(bin_dir, "oilfilm-estimator"), "--ros-args", "-r", f"__node:={FOLLOWER}",
                                 "-r", f"__ns:={FOLLOWER_NS}", "-p", "use_sim_time:=true"],
                                stdout=follower_log, stderr=subprocess.STDOUT)
    setter = node.create_client(SetParameters, f"{follower_name}/set_parameters")
    found = setter.wait_for_service(timeout_sec=30.0)
    check(found, f"{follower_name} (use_sim_time:=true) serves its parameters")
    deadline = time.monotonic() + 1.0
    while time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.05)

    player = subprocess.Popen([os.path.join(bin_dir, "oilfilm"), "play", bag, "--rate", "2", "--wait-s", "20"],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    clock_types = set()
    try:
        deadline = time.monotonic() + 90
        while player.poll() is None and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.02)
            for name, types in node.get_topic_names_and_types():
                if name == "/clock":
                    clock_types.update(types)
        end = time.monotonic() + 1.0
        while time.monotonic() < end:
            executor.spin_once(timeout_sec=0.02)
    finally:
        if player.poll() is None:
            player.kill()
    check(player.wait() == 0, "oilfilm play exits 0 at the end of the bag")

    check("rosgraph_msgs/msg/Clock" in clock_types, f"/clock is offered as rosgraph_msgs/msg/Clock (types seen: {sorted(clock_types)})")
    check(len(clocks) > 10, f"{len(clocks)} /clock messages received")
    check(all(b >= a for a, b in zip(clocks, clocks[1:])), "/clock never goes backwards")
    check(bool(clocks) and clocks[-1] == last_log, f"/clock ends at the bag's last log time ({clocks[-1] if clocks else None} vs {last_log})")
    check(bool(clocks) and clocks[0] >= min(m["log_time"] for m in expected), "/clock starts at the bag's log time")
    now = node.get_clock().now().nanoseconds
    check(now == last_log, f"the use_sim_time node's clock follows /clock to the bag's end ({now} vs {last_log})")

    try:
        if found:
            request = SetParameters.Request(parameters=[ParameterMsg(name="max_condition", value=ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=2e6))])
            future = setter.call_async(request)
            t0 = time.monotonic()
            while time.monotonic() - t0 < 20 and not (future.done() and any(e.changed_parameters for e in events)
                                                      and any("max_condition" in m.msg for m in logs)):
                executor.spin_once(timeout_sec=0.05)
            check(future.done() and future.result().results[0].successful, "the set on our use_sim_time node is applied")
            changed = [e for e in events if any(p.name == "max_condition" for p in e.changed_parameters)]
            wall = time.time_ns()
            check(bool(changed) and ns(changed[-1].stamp) == last_log,
                  f"our use_sim_time node stamps its parameter event with /clock's time, the bag's last log time "
                  f"({ns(changed[-1].stamp) if changed else None} vs {last_log}; the wall clock: {wall})")
            said = [m for m in logs if "max_condition" in m.msg]
            check(bool(said) and ns(said[-1].stamp) == last_log,
                  f"and its /rosout line about it ({ns(said[-1].stamp) if said else None} vs {last_log})")
    finally:
        follower.send_signal(signal.SIGINT)
        try:
            check(follower.wait(timeout=20) == 0, "our use_sim_time node exits 0 on SIGINT")
        except subprocess.TimeoutExpired:
            follower.kill()
            check(False, "our use_sim_time node exits on SIGINT within 20 s")
        follower_log.close()
        if failures:
            with open(follower_log.name, errors="replace") as f:
                sys.stderr.write(f"{follower_name}'s output:\n" + f.read()[-4000:])

    for t, (ty, want) in topics.items():
        have = got[t]
        check(len(have) == len(want), f"{t}: {len(have)} of {len(want)} messages")
        stamps_ok = all(ns(h.header.stamp) == w["value"]["header"]["stamp"]["sec"] * 1_000_000_000 + w["value"]["header"]["stamp"]["nanosec"]
                        for h, w in zip(have, want))
        check(stamps_ok, f"{t}: header stamps are the recorded ones, in order")
        if ty == "oilfilm_msgs/msg/DaqFrame":
            # Samples are in values (SI, volts) or counts (the ADC's codes, as the DAQ node
            # sends them): both compared whole, and the frames must hold some.
            def same_samples(h, w):
                v = w["value"]
                return (h.sequence == v["sequence"] and h.units == v["units"]
                        and len(h.values) == len(v["values"]) and all(same(a, b) for a, b in zip(h.values.tolist(), v["values"]))
                        and h.counts.tolist() == v.get("counts", []) and h.volts_per_count.tolist() == v.get("volts_per_count", []))
            check(all(same_samples(h, w) for h, w in zip(have, want)), f"{t}: frame sequences, units and samples as recorded")
            check(all(len(w["value"]["values"]) + len(w["value"].get("counts", [])) > 0 for w in want),
                  f"{t}: every recorded frame holds samples ({sum(len(w['value'].get('counts', [])) for w in want)} counts)")
    node.destroy_node()
    rclpy.shutdown()
    print("rclpy player interop: " + ("ok" if not failures else f"{len(failures)} failure(s)"))
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
