#!/usr/bin/env python3
"""Every oilfilm_msgs message goes through DDS (rmw_fastrtps, loopback) from an rclpy
publisher to an rclpy subscriber and arrives equal. Proves the built package works at run
time. Run through run-rclpy-roundtrip.sh (sets the environment and a random domain)."""
import os
import sys
import time

import rclpy
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy, DurabilityPolicy

sys.path.insert(0, os.path.dirname(__file__))
import check_msgs  # noqa: E402  (the fixture cases)


def main():
    rclpy.init()
    qos = QoSProfile(depth=10, history=HistoryPolicy.KEEP_LAST,
                     reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
    pub_node = rclpy.create_node("oilfilm_roundtrip_pub")
    sub_node = rclpy.create_node("oilfilm_roundtrip_sub")
    executor = rclpy.executors.SingleThreadedExecutor()
    executor.add_node(pub_node)
    executor.add_node(sub_node)
    expected, received, pubs = {}, {}, []
    for name, cls, make in check_msgs.TYPES:
        topic = f"/oilfilm_test/{name}"
        cases = [m for _, m in make()]
        expected[name] = cases
        received[name] = []
        sub_node.create_subscription(cls, topic, lambda m, n=name: received[n].append(m), qos)
        pubs.append((pub_node.create_publisher(cls, topic, qos), cases))
    # Wait for discovery of every subscription, then publish.
    deadline = time.monotonic() + 20.0
    while any(p.get_subscription_count() == 0 for p, _ in pubs):
        if time.monotonic() > deadline:
            print("FAIL: subscribers not discovered in 20 s", file=sys.stderr)
            return 1
        executor.spin_once(timeout_sec=0.05)
    for p, cases in pubs:
        for m in cases:
            p.publish(m)
    deadline = time.monotonic() + 20.0
    while any(len(received[n]) < len(expected[n]) for n in expected):
        if time.monotonic() > deadline:
            break
        executor.spin_once(timeout_sec=0.05)
    failures = 0
    for n in expected:
        if received[n] != expected[n]:
            print(f"FAIL {n}: sent {len(expected[n])}, received {len(received[n])}"
                  f"{' (values differ)' if len(received[n]) == len(expected[n]) else ''}", file=sys.stderr)
            failures += 1
        else:
            print(f"{n}: {len(received[n])} message(s) received equal")
    pub_node.destroy_node()
    sub_node.destroy_node()
    rclpy.shutdown()
    print("rclpy roundtrip: " + ("ok" if not failures else f"{failures} failure(s)"))
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
