#!/usr/bin/env python3
"""Our graph seen through the real `ros2` command line (ros2cli on the rclpy wheels,
rmw_fastrtps, loopback, `--no-daemon` so each command is a fresh participant).

Against `oilfilm launch tests/interop/live/sim_rig.launch.yaml`:
1. `ros2 node list` lists the four nodes; `ros2 topic list -t` our topics with their types,
   and `/clock` (the DAQ runs at rate_factor 2, so its stamps are not the wall clock's) with
   exactly one type, rosgraph_msgs/msg/Clock;
2. `ros2 topic info -v` names the estimator as the publisher of `estimates`, volatile, and
   the exciter as the publisher of `exciter/command` (a writer made outside ros2-client);
3. `ros2 topic echo --once` prints a RigStatus and a `/clock`; `ros2 topic hz` measures the
   DAQ frames near their rate (10 frames/s of rig time at rate_factor 2: 20/s);
4. `ros2 param list/describe/get/set`: descriptions, ranges and read-only flags shown, a
   valid set applied (get returns it), a useless value refused with the rule, and a later
   set still applied; the refusal reaches `/rosout` as a warning of the node's logger;
5. `ros2 service list` shows each node's six parameter services;
and during `oilfilm play` of a bag: `/clock` echoes with one type and the played topics'
publisher is the player node, through the daemon and to a fresh participant. No command prints
an error or a warning.

Run through run-ros2-cli.sh.
"""

import os
import re
import signal
import subprocess
import sys
import tempfile
import time

sys.path.insert(0, os.path.dirname(__file__))
from test_rclpy_live import NS, ROOT, check, failures  # noqa: E402

NODES = ["conditioner", "daq", "estimator", "exciter"]
PARAM_SERVICES = ["describe_parameters", "get_parameter_types", "get_parameters", "list_parameters", "set_parameters", "set_parameters_atomically"]


def ros2(*args, timeout=40):
    """`ros2 ARGS` with a fresh participant; returns (exit code, stdout, stderr)."""
    cmd = ["ros2", *args]
    if args[0] in ("node", "topic", "service", "param") and args[1] != "hz":
        cmd.append("--no-daemon")
    try:
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
        return r.returncode, r.stdout, r.stderr
    except subprocess.TimeoutExpired as e:
        out = e.stdout.decode(errors="replace") if isinstance(e.stdout, bytes) else (e.stdout or "")
        err = e.stderr.decode(errors="replace") if isinstance(e.stderr, bytes) else (e.stderr or "")
        return None, out, err


def noisy(stderr):
    """The error and warning lines a command printed."""
    return [line for line in stderr.splitlines() if re.search(r"error|warn|fail|traceback", line, re.I)]


def until(pred, timeout_s, step_s=1.0):
    deadline = time.monotonic() + timeout_s
    while True:
        v = pred()
        if v or time.monotonic() > deadline:
            return v
        time.sleep(step_s)


def retry(args, ok, timeout_s=40):
    """A command again until `ok(stdout)` (a fresh participant can miss a service: ADR 0017)."""
    last = [None, "", ""]

    def once():
        last[:] = ros2(*args)
        return last[0] == 0 and ok(last[1] + last[2])
    until(once, timeout_s, 2.0)
    return last


def live(oilfilm):
    log = tempfile.NamedTemporaryFile(prefix="oilfilm-cli-launch-", suffix=".log", delete=False)
    launch = subprocess.Popen([oilfilm, "launch", os.path.join(ROOT, "tests/interop/live/sim_rig.launch.yaml"), "--seconds", "240"],
                              stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
    rosout = None
    try:
        # 1. Nodes and topics.
        rc, out, err = retry(["node", "list"], lambda o: all(f"{NS}/{n}" in o.split() for n in NODES), 60)
        check(rc == 0 and all(f"{NS}/{n}" in out.split() for n in NODES), f"ros2 node list: {sorted(out.split())}")
        check(not noisy(err), f"ros2 node list prints no error or warning {noisy(err)}")
        rc, out, err = retry(["topic", "list", "-t"], lambda o: f"{NS}/estimates" in o and "/clock" in o, 60)
        types = dict(re.findall(r"^(\S+) \[(.+)\]$", out, re.M))
        want = {f"{NS}/estimates": "oilfilm_msgs/msg/CoefficientEstimate", f"{NS}/daq/frames": "oilfilm_msgs/msg/DaqFrame",
                f"{NS}/rig/status": "oilfilm_msgs/msg/RigStatus", f"{NS}/conditioned": "oilfilm_msgs/msg/ConditionedFrame",
                f"{NS}/exciter/command": "oilfilm_msgs/msg/ExciterCommand", "/clock": "rosgraph_msgs/msg/Clock",
                "/rosout": "rcl_interfaces/msg/Log", "/parameter_events": "rcl_interfaces/msg/ParameterEvent"}
        for topic, ty in want.items():
            check(types.get(topic) == ty, f"ros2 topic list -t: {topic} [{types.get(topic)}] (one type: {ty})")
        check(not noisy(err), f"ros2 topic list prints no error or warning {noisy(err)}")

        # 2. topic info -v.
        rc, out, err = ros2("topic", "info", "-v", f"{NS}/estimates")
        pubs = out.split("Subscription count")[0]
        check(rc == 0 and "Node name: estimator" in pubs and f"Node namespace: {NS}" in pubs and "VOLATILE" in pubs,
              "ros2 topic info -v: estimates published by /oilfilm/estimator, volatile")
        # The exciter's writer is made outside ros2-client (it waits for acknowledgments), so
        # ros2-client's own announcement of the node leaves it out; ours lists it and is sent
        # again to each newly joined participant. Each try is a fresh participant.
        names = []
        for _ in range(3):
            rc, out, err = ros2("topic", "info", "-v", f"{NS}/exciter/command")
            names = re.findall(r"Node name: (\S+)", out.split("Subscription count")[0])
            if names == ["exciter"]:
                break
        check(names == ["exciter"], f"ros2 topic info -v: exciter/command published by /oilfilm/exciter ({names})")
        hashes = re.findall(r"Topic type hash: (\S+)", pubs)
        print(f"note: type hash of our estimates writer as ros2 sees it: {hashes} (RustDDS sends none: ADR 0025)")
        check(not noisy(err), f"ros2 topic info -v prints no error or warning {noisy(err)}")

        # 3. echo and hz.
        rc, out, err = ros2("topic", "echo", "--once", f"{NS}/rig/status", timeout=30)
        check(rc == 0 and "speed_rad_s: 157.07" in out, "ros2 topic echo --once rig/status: the rig at 1500 rpm")
        rc, out, err = ros2("topic", "echo", "--once", "/clock", timeout=30)
        check(rc == 0 and re.search(r"clock:\s+sec: \d+", out) is not None and not noisy(err), "ros2 topic echo --once /clock: one type, it echoes")
        rc, out, err = ros2("topic", "hz", f"{NS}/daq/frames", "--window", "20", timeout=12)
        rates = [float(x) for x in re.findall(r"average rate: ([0-9.]+)", out)]
        check(bool(rates) and 14.0 < rates[-1] < 26.0, f"ros2 topic hz daq/frames: {rates[-1] if rates else None} /s (20 expected at rate_factor 2)")

        # 4. Parameters, with /rosout watched for the refusal.
        rosout = subprocess.Popen(["ros2", "topic", "echo", "/rosout", "rcl_interfaces/msg/Log", "--no-daemon", "--qos-durability", "volatile", "--qos-reliability", "reliable"],
                                  stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True)
        rc, out, err = retry(["param", "list", f"{NS}/estimator"], lambda o: "window" in o)
        check(rc == 0 and all(p in out.split() for p in ["window", "hop", "model", "solver", "use_sim_time"]), "ros2 param list estimator")
        rc, out, err = retry(["param", "describe", f"{NS}/estimator", "window"], lambda o: "Description" in o)
        check(rc == 0 and "Type: integer" in out and re.search(r"Description: \S", out) is not None and "Min value" in out,
              "ros2 param describe estimator window: a description and a range")
        rc, out, err = retry(["param", "describe", f"{NS}/daq", "block_scans"], lambda o: "Description" in o)
        check(rc == 0 and "Read only: true" in out, "ros2 param describe daq block_scans: read only")
        rc, out, err = retry(["param", "set", f"{NS}/estimator", "hop", "5000"], lambda o: "Set parameter" in o)
        check(rc == 0 and "Set parameter successful" in out, f"ros2 param set estimator hop 5000: {out.strip()}")
        rc, out, err = retry(["param", "get", f"{NS}/estimator", "hop"], lambda o: "value" in o)
        check(rc == 0 and "Integer value is: 5000" in out, f"ros2 param get estimator hop: {out.strip()}")
        rc, out, err = retry(["param", "set", f"{NS}/estimator", "window", "3"], lambda o: "parameter" in o.lower())
        said = out + err  # ros2 param set prints a refusal on stderr and exits 0
        check("failed" in said and "window" in said, f"ros2 param set estimator window 3 refused naming it: {said.strip()}")
        rc, out, err = retry(["param", "set", f"{NS}/estimator", "max_condition", ".nan"], lambda o: "parameter" in o.lower())
        said = out + err
        check("failed" in said and "max_condition" in said and "null" not in said, f"ros2 param set estimator max_condition .nan refused naming it: {said.strip()}")
        rc, out, err = retry(["param", "set", f"{NS}/conditioner", "lowpass_cutoff_hz", "40.0"], lambda o: "parameter" in o.lower())
        said = out + err
        check("failed" in said and "read-only" in said, f"ros2 param set conditioner lowpass_cutoff_hz refused, read-only: {said.strip()}")
        rc, out, err = retry(["param", "set", f"{NS}/estimator", "hop", "10000"], lambda o: "Set parameter" in o)
        check("successful" in out, "after a refusal a valid set is still applied")
        rc, out, err = retry(["param", "get", f"{NS}/estimator", "hop"], lambda o: "value" in o)
        check("Integer value is: 10000" in out, f"ros2 param get estimator hop after it: {out.strip()}")
        time.sleep(2)
        os.killpg(rosout.pid, signal.SIGINT)
        logged = rosout.communicate(timeout=10)[0]
        blocks = logged.split("---")
        check(any("level: 30" in b and "name: oilfilm.estimator" in b and "window" in b for b in blocks),
              "the refused set reached /rosout as a warning (level 30) of logger oilfilm.estimator")

        # 5. Services.
        rc, out, err = retry(["service", "list"], lambda o: all(f"{NS}/{n}/{s}" in o for n in NODES for s in PARAM_SERVICES), 60)
        missing = [f"{n}/{s}" for n in NODES for s in PARAM_SERVICES if f"{NS}/{n}/{s}" not in out.split()]
        check(rc == 0 and not missing, f"ros2 service list: every node's six parameter services" + (f" (missing {missing})" if missing else ""))
        check(not noisy(err), f"ros2 service list prints no error or warning {noisy(err)}")
    finally:
        if rosout is not None and rosout.poll() is None:
            os.killpg(rosout.pid, signal.SIGKILL)
        launch.send_signal(signal.SIGINT)
        try:
            launch.wait(timeout=30)
        except subprocess.TimeoutExpired:
            os.killpg(launch.pid, signal.SIGKILL)
            launch.wait()
        log.close()
        with open(log.name, errors="replace") as f:
            text = f.read()
        # The refused sets above are warnings by design; nothing else may be.
        bad = [line for line in text.splitlines() if re.search(r"\b(ERROR|WARN)\b", line) and "parameters not set" not in line]
        check(not bad, f"the launched nodes logged no error or warning but the refusals {bad[:3]}")
        if failures:
            sys.stderr.write(text[-4000:])
        os.unlink(log.name)


def playing(oilfilm, bag):
    subprocess.run(["ros2", "daemon", "start"], capture_output=True, timeout=40)
    log = tempfile.NamedTemporaryFile(prefix="oilfilm-cli-play-", suffix=".log", delete=False)
    player = subprocess.Popen([oilfilm, "play", bag, "--rate", "0.25", "--wait-s", "0"], stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
    try:
        rc, out, err = retry(["topic", "list", "-t"], lambda o: f"{NS}/daq/frames" in o and "/clock" in o, 30)
        check(re.search(r"^/clock \[rosgraph_msgs/msg/Clock\]$", out, re.M) is not None, "during oilfilm play: /clock has one type, rosgraph_msgs/msg/Clock")
        rc, out, err = ros2("topic", "echo", "--once", "/clock", timeout=30)
        check(rc == 0 and "clock:" in out and not noisy(err), "during oilfilm play: ros2 topic echo --once /clock")
        # The played topics' writers are raw ones, which ros2-client's own announcement of the
        # node leaves out. The daemon, running before the player started, keeps our
        # announcements; a fresh participant is sent ours again when it joins (ADR 0017).
        time.sleep(3)
        for how, extra in (("through the daemon", []), ("to a fresh participant (--no-daemon)", ["--no-daemon"])):
            pubs = ""
            for _ in range(5):
                r = subprocess.run(["ros2", "topic", "info", "-v", f"{NS}/daq/frames", *extra], capture_output=True, text=True, timeout=40)
                pubs = r.stdout.split("Subscription count")[0]
                if "Node name: player" in pubs:
                    break
                time.sleep(2)
            names = re.findall(r"Node name: (\S+)", pubs)
            check(names == ["player"], f"during oilfilm play: the played topic's publisher is the player node, {how} ({names})")
        rc, out, err = ros2("topic", "echo", "--once", f"{NS}/rig/status", timeout=30)
        check(rc == 0 and "speed_rad_s" in out, "during oilfilm play: ros2 topic echo --once rig/status")
    finally:
        player.send_signal(signal.SIGINT)
        try:
            player.wait(timeout=20)
        except subprocess.TimeoutExpired:
            os.killpg(player.pid, signal.SIGKILL)
            player.wait()
        log.close()
        with open(log.name, errors="replace") as f:
            text = f.read()
        # --wait-s 0: it says it played without waiting for subscribers; nothing else.
        bad = [line for line in text.splitlines() if re.search(r"\b(ERROR|WARN)\b|Inconsistent topic", line) and "playing anyway" not in line]
        check(not bad, f"the player logged no error or warning but that it did not wait {bad[:3]}")
        if failures:
            sys.stderr.write(text[-3000:])
        os.unlink(log.name)


def main():
    oilfilm = os.path.join(sys.argv[1], "oilfilm")
    live(oilfilm)
    playing(oilfilm, sys.argv[2])
    print("ros2 command line: " + ("ok" if not failures else f"{len(failures)} failure(s)"))
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
