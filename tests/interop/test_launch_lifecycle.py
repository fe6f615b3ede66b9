#!/usr/bin/env python3
"""`oilfilm launch` as a process tree: what it says when a run gave nothing, and what its
nodes do when it dies without stopping them (rclpy, rmw_fastrtps, loopback).

1. A run whose estimator cannot finish a window (its window longer than the run) exits
   non-zero, and its error names the estimator as the silent node, with what the nodes
   upstream of it published.
2. SIGKILL of the launcher alone (no SIGINT, no chance to stop its nodes): every node
   process exits on its own (the parent-death signal), and the exciter's last command, seen
   from rclpy, is a ramp to zero that never steps by more than the rig's slew limit.

Run through run-launch-lifecycle.sh (environment, a random domain, the binaries' directory).
"""

import os
import signal
import subprocess
import sys
import tempfile
import time

import rclpy
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from oilfilm_msgs.msg import DaqFrame, ExciterCommand

sys.path.insert(0, os.path.dirname(__file__))
from test_rclpy_live import NS, ROOT, check, check_no_step, failures, spin_until  # noqa: E402


def group_alive(pgid):
    """Pids of the process group `pgid` that are still running (zombies do not count: they
    have exited and only wait for their parent to reap them)."""
    alive = []
    for pid in filter(str.isdigit, os.listdir("/proc")):
        try:
            with open(f"/proc/{pid}/stat") as f:
                stat = f.read()
        except OSError:
            continue
        # comm may hold spaces: the fields after its closing parenthesis are fixed.
        fields = stat[stat.rindex(")") + 2:].split()
        if int(fields[2]) == pgid and fields[0] != "Z":
            alive.append(int(pid))
    return alive


def no_estimate(oilfilm):
    """1. The estimator's 40 s window in a 14 s run. Its DAQ runs at real time (rate_factor 1),
    so its frames are stamped with the wall clock: a frame arrives just after the wall-clock
    time of the scan after its last (its stamp + scan_count / rate)."""
    rclpy.init()
    node = rclpy.create_node("oilfilm_rclpy_stamp_probe")
    executor = rclpy.executors.SingleThreadedExecutor()
    executor.add_node(node)
    lags = []

    def frame(f):
        end_ns = f.header.stamp.sec * 1_000_000_000 + f.header.stamp.nanosec + round(f.scan_count * 1e9 / f.sample_rate_hz)
        lags.append((time.time_ns() - end_ns) * 1e-9)
    node.create_subscription(DaqFrame, f"{NS}/daq/frames", frame,
                             QoSProfile(depth=200, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE))
    launch_file = os.path.join(ROOT, "tests/interop/live/silent_estimator.launch.yaml")
    # Long enough for the graph to be discovered even when the nodes' first discovery messages
    # are lost (a loaded machine): RustDDS announces a participant again only every 10 s, and
    # the DAQ publishes nothing until it has a subscriber.
    run = subprocess.Popen([oilfilm, "launch", launch_file, "--seconds", "14"], stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                           text=True, start_new_session=True)
    try:
        spin_until(executor, lambda: run.poll() is not None, 120)
        out = run.communicate(timeout=30)[0]
    finally:
        if run.poll() is None:
            os.killpg(run.pid, signal.SIGKILL)
            run.wait()
        node.destroy_node()
        rclpy.shutdown()
    check(run.returncode != 0, f"a run without an estimate exits non-zero (exit {run.returncode})")
    said = [line for line in out.splitlines() if line.startswith("Error: ")]
    check(bool(said) and "node `estimator` published nothing" in said[0] and "conditioner published" in said[0] and "daq published" in said[0],
          f"its error names the silent estimator and what the nodes upstream published: {said[0] if said else '(none)'}")
    check("0 estimate(s) received" in out, "it counts the estimates it received (0)")
    # The least lag is the transport's alone: within 20 ms of the wall clock (a DAQ that
    # took its start before waiting for subscribers lagged ~0.6 s; one run 4x fast, seconds ahead).
    # Ten frames are enough for that: the DAQ's first block waits for its exciter's setpoints,
    # which on a loaded machine take seconds of the run (discovery), and the frames of that
    # wait come late until the rig has caught up.
    lags.sort()
    on_time = check(len(lags) >= 10 and abs(lags[0]) < 0.020 and lags[len(lags) // 2] < 0.2,
                    f"at rate_factor 1 a DAQ frame's end stamp is the wall clock's: least lag {1e3 * lags[0]:.1f} ms, median "
                    f"{1e3 * lags[len(lags) // 2]:.1f} ms over {len(lags)} frames" if lags else "no DAQ frame received")
    if not on_time:
        # What the nodes warned of (a DAQ that waited for setpoints says so): the reason.
        sys.stderr.writelines(line + "\n" for line in out.splitlines() if " WARN " in line)


def launcher_killed(oilfilm):
    """2. SIGKILL of the launcher while the exciter runs a 400 N two-tone."""
    rclpy.init()
    node = rclpy.create_node("oilfilm_rclpy_launch_probe")
    executor = rclpy.executors.SingleThreadedExecutor()
    executor.add_node(node)
    got = []
    keep_all = QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE)
    node.create_subscription(ExciterCommand, f"{NS}/exciter/command", got.append, keep_all)
    log = tempfile.NamedTemporaryFile(prefix="oilfilm-launch-killed-", suffix=".log", delete=False)
    launch = subprocess.Popen([oilfilm, "launch", os.path.join(ROOT, "tests/interop/live/sim_rig.launch.yaml"), "--seconds", "120"],
                              stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
    pgid = launch.pid
    try:
        running = lambda: [c for c in got if not c.stop and c.force_1_n and max(map(abs, c.force_1_n)) > 390.0]
        spin_until(executor, lambda: len(running()) >= 5, 60)
        check(len(running()) >= 5, "the launched exciter runs its 400 N two-tone")
        nodes = [p for p in group_alive(pgid) if p != launch.pid]
        check(len(nodes) == 4, f"the launcher runs four node processes ({len(nodes)})")
        os.kill(launch.pid, signal.SIGKILL)
        launch.wait()
        spin_until(executor, lambda: not group_alive(pgid), 30)
        left = group_alive(pgid)
        check(not left, "after SIGKILL of the launcher every node exits on its own" + (f" (still running: {left})" if left else ""))
        spin_until(executor, lambda: False, 1.0)
        stops = [c for c in got if c.stop]
        check(bool(stops) and stops[-1].force_1_n[-1] == 0.0 and stops[-1].force_2_n[-1] == 0.0,
              "the exciter's last command is a ramp to zero (stop = true)")
        if got:
            check_no_step(got, [(400.0, 37.0, 0.2)], "the exciter's start and its stop when the launcher died")
    finally:
        try:
            os.killpg(pgid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        log.close()
        if failures:
            with open(log.name, errors="replace") as f:
                sys.stderr.writelines(f.readlines()[-40:])
        else:
            os.unlink(log.name)
        node.destroy_node()
        rclpy.shutdown()


def main():
    oilfilm = os.path.join(sys.argv[1], "oilfilm")
    no_estimate(oilfilm)
    launcher_killed(oilfilm)
    print("launch lifecycle: " + ("ok" if not failures else f"{len(failures)} failure(s)"))
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
