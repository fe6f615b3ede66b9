#!/usr/bin/env python3
"""Serialise every oilfilm_msgs message with rclpy and write golden CDR fixtures.

Run with the environment printed by tests/interop/setup-ros-venv.sh (run-check-msgs.sh
does both). For each case it builds the message with non-trivial values, serialises it
with rclpy.serialization.serialize_message (rmw_fastrtps's CDR), checks that
deserialize_message gives the same values back, and writes

    tests/data/cdr/<Type>.json = {"type": ..., "cases": [{"name", "value", "cdr_hex"}]}

`value` is the message as JSON with the .msg field names, so the Rust test can build the
same value through serde. Values are finite (JSON has no NaN).

It also copies the dependency definitions the bag schemas need (std_msgs/Header,
builtin_interfaces/Time, rosgraph_msgs/Clock for the player, and rcl_interfaces/ParameterEvent with
Parameter and ParameterValue for the recorder) from the installed share directories into crates/msgs/upstream/.

Note: Fast-CDR does not zero alignment padding, so padding bytes in cdr_hex may be any
value; the Rust test compares every other byte.

Usage: check_msgs.py [--out DIR] [--check]   (--check: compare with the committed fixtures
instead of writing them; padding-insensitive comparison is the Rust test's job, so --check
only compares lengths and values.)
"""
import argparse
import json
import math
import os
import sys

import numpy
from rclpy.serialization import deserialize_message, serialize_message
from ament_index_python.packages import get_package_share_directory

from builtin_interfaces.msg import Time
from std_msgs.msg import Header
from rosgraph_msgs.msg import Clock
from oilfilm_msgs.msg import (
    CoefficientEstimate,
    ConditionedFrame,
    DaqFrame,
    ExciterCommand,
    RigStatus,
)

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), "..", ".."))


def header(sec, nanosec, frame_id="oilfilm_bearing"):
    return Header(stamp=Time(sec=sec, nanosec=nanosec), frame_id=frame_id)


def to_plain(msg):
    """A message (or field value) as JSON-able Python values, keyed by .msg field names."""
    if hasattr(msg, "get_fields_and_field_types"):
        return {name: to_plain(getattr(msg, name)) for name in msg.get_fields_and_field_types()}
    if isinstance(msg, numpy.ndarray):
        return [to_plain(v) for v in msg.tolist()]
    if isinstance(msg, (list, tuple)) or type(msg).__name__ == "array":
        return [to_plain(v) for v in msg]
    if isinstance(msg, numpy.generic):
        return msg.item()
    if isinstance(msg, float):
        assert math.isfinite(msg), "fixtures must be finite"
    return msg


def exciter_cases():
    m = ExciterCommand()
    m.header = header(1_700_000_000, 250_000_000)
    m.sequence = 42
    m.waveform = [ExciterCommand.WAVEFORM_SINE, ExciterCommand.WAVEFORM_MULTISINE]
    m.amplitude_n = [100.0, 0.0]
    m.frequency_hz = [20.0, 0.0]
    m.phase_rad = [0.25, 0.0]
    m.rms_n = [0.0, 70.7]
    m.period_s = [0.0, 1.0]
    m.band_low_hz = [0.0, 5.0]
    m.band_high_hz = [0.0, 75.0]
    m.line_set = [ExciterCommand.LINES_ALL, ExciterCommand.LINES_ODD]
    m.chirp_start_hz = [0.0, 0.0]
    m.chirp_end_hz = [0.0, 0.0]
    m.sweep_s = [0.0, 0.0]
    m.ramp_s = 0.5
    m.amplitude_scale = 0.75
    m.setpoint_rate_hz = 5000.0
    m.force_1_n = [0.0, 2.5, -3.25, 1499.0]
    m.force_2_n = [0.0, -1.0, 7.5, -1500.0]
    m.max_force_n = 1500.0
    m.band_limit_low_hz = 0.0
    m.band_limit_high_hz = 80.0
    m.stop = False
    s = ExciterCommand()
    s.header = header(1_700_000_001, 0, "")
    s.sequence = 43
    s.max_force_n = 1500.0
    s.band_limit_high_hz = 80.0
    s.stop = True
    return [("sine_and_multisine_with_setpoints", m), ("stop_without_setpoints", s)]


def daq_cases():
    names = ["probe_a_x", "probe_a_y", "probe_b_x", "probe_b_y", "frame_x", "frame_y",
             "f1", "f2", "f3", "temperature"]
    units = ["m", "m", "m", "m", "m", "m", "N", "N", "N", "degC"]
    m = DaqFrame()
    m.header = header(12, 345_678_901)
    m.sequence = 7
    m.first_scan = 350
    m.sample_rate_hz = 5000.0
    m.units = DaqFrame.UNITS_SI
    m.channel_names = names
    m.channel_units = units
    m.channel_offsets_s = [p * 1e-5 for p in range(10)]
    m.scan_count = 2
    m.values = [4.8833e-05, -7.9731e-05, 4.9289e-05, -7.9429e-05, 2.7105e-09, -5.1452e-08,
                0.23, 0.93, 5603.2, 29.003,
                4.8908e-05, -7.9691e-05, 4.9274e-05, -7.9428e-05, 5.643e-10, -4.1409e-08,
                3.66, 5.24, 5601.8, 28.999]
    m.rig = "zhou2004"
    v = DaqFrame()
    v.header = header(0, 1)
    v.sequence = 1
    v.first_scan = 0
    v.sample_rate_hz = 100000.0
    v.units = DaqFrame.UNITS_VOLTS
    v.channel_names = ["f1", "f2", "f3"]
    v.channel_units = ["V", "V", "V"]
    # An empty float64[] followed by a uint32: no padding before the (absent) elements.
    v.channel_offsets_s = []
    v.scan_count = 1
    v.values = [1.25, -0.5, 9.999]
    v.rig = "zhou2004.toml"
    # ADC counts: values empty, the int16 sequence after the float64 one (an odd count of
    # them, a rig name that leaves the float64[] length unaligned).
    c = DaqFrame()
    c.header = header(7, 8)
    c.sequence = 2
    c.first_scan = 1000
    c.sample_rate_hz = 5000.0
    c.units = DaqFrame.UNITS_COUNTS
    c.channel_names = ["probe_a_x", "f1", "temperature"]
    c.channel_units = ["V", "V", "V"]
    c.channel_offsets_s = [0.0, 1e-5, 2e-5]
    c.scan_count = 1
    c.values = []
    c.rig = "zhou"
    c.volts_per_count = [20.0 / 65536] * 3
    c.counts = [-32768, 1234, 32767]
    return [("si_two_scans", m), ("volts_empty_offsets", v), ("counts_int16", c)]


def conditioned_cases():
    m = ConditionedFrame()
    m.header = header(100, 200)
    m.sequence = 3
    m.first_sample = 1024
    m.sample_rate_hz = 5000.0
    m.x_m = [1e-6, 2e-6, -3e-6]
    m.y_m = [-1e-6, 0.5e-6, 4e-6]
    m.x_dot_m_s = [1e-3, -2e-3, 3e-3]
    m.y_dot_m_s = [4e-3, 5e-3, -6e-3]
    m.x_ddot_m_s2 = [0.1, 0.2, 0.3]
    m.y_ddot_m_s2 = [-0.1, -0.2, -0.3]
    m.fx_n = [10.5, -20.25, 30.0]
    m.fy_n = [-40.0, 50.125, -60.0]
    m.valid = [True, False, True]
    m.bearing_temperature_degc = 41.25
    m.flags = ["lowpass_hz=55.5", "deskewed"]
    k = ConditionedFrame()
    k.header = header(100, 300)
    k.sequence = 4
    k.first_sample = 1027
    k.sample_rate_hz = 5000.0
    k.x_m = [1e-6]
    k.y_m = [2e-6]
    k.x_dot_m_s = [3e-3]
    k.y_dot_m_s = [4e-3]
    k.x_ddot_m_s2 = []
    k.y_ddot_m_s2 = []
    k.fx_n = [5.0]
    k.fy_n = [6.0]
    k.valid = [True]
    k.flags = []
    return [("kcm_three_samples", m), ("kc_no_accelerations", k)]


def estimate_cases():
    m = CoefficientEstimate()
    m.header = header(1_700_000_010, 5)
    m.sequence = 9
    m.window_start = Time(sec=1_700_000_000, nanosec=0)
    m.window_end = Time(sec=1_700_000_002, nanosec=500_000_000)
    m.window_start_sample = 0
    m.window_end_sample = 12500
    m.model = CoefficientEstimate.MODEL_KCM
    m.solved = True
    m.refusal_reason = ""
    m.stiffness_n_m = [1.2e8, 3.4e7, -5.6e7, 2.1e8]
    m.damping_n_s_m = [4.5e5, 1.1e4, 1.2e4, 6.7e5]
    m.stiffness_se_n_m = [1.2e6, 3.4e5, 5.6e5, 2.1e6]
    m.damping_se_n_s_m = [4.5e3, 1.1e2, 1.2e2, 6.7e3]
    m.added_mass_kg = [12.0, -1.5, 0.25, 9.0]
    m.added_mass_se_kg = [2.0, 1.0, 1.0, 2.0]
    m.stiffness_lund = [1.1, 0.3, -0.5, 1.9]
    m.damping_lund = [2.2, 0.1, 0.1, 3.3]
    m.stiffness_zhou = [0.55, 0.15, -0.25, 0.95]
    m.damping_zhou = [1.1, 0.05, 0.05, 1.65]
    m.condition_number = 37.5
    m.rank = 6
    m.residual_rms_n = [3.5, 4.25]
    m.excitation_frequencies_hz = [20.0, 30.0, 37.0]
    m.flags = ["lowpass narrowed to 55.5 Hz"]
    m.speed_rad_s = 157.07963267948966
    m.bearing_temperature_degc = 29.0
    m.viscosity_pa_s = 0.0185
    m.static_force_n = [12.5, 5000.0]
    m.load_n = 5000.015625
    m.journal_position_m = [5e-5, -8e-5]
    m.sommerfeld_number = 0.63
    m.load_parameter_fy = 0.505
    m.amplitude_d = 0.021
    r = CoefficientEstimate()
    r.header = header(1_700_000_011, 0)
    r.sequence = 10
    r.window_start = Time(sec=1_700_000_001, nanosec=250_000_000)
    r.window_end = Time(sec=1_700_000_003, nanosec=750_000_000)
    r.window_start_sample = 6250
    r.window_end_sample = 18750
    r.model = CoefficientEstimate.MODEL_KC
    r.solved = False
    r.refusal_reason = ("cannot separate the coefficients: both exciters at one frequency "
                        "leave x, y, x', y' in span{cos, sin} (rank 2 of 4)")
    # Refused: the real node sends NaN coefficients; fixtures are finite (JSON), so zeros.
    r.added_mass_kg = []
    r.added_mass_se_kg = []
    r.condition_number = 1.0e17
    r.rank = 2
    r.residual_rms_n = [0.0, 0.0]
    r.excitation_frequencies_hz = [20.0]
    r.flags = []
    r.speed_rad_s = 157.07963267948966
    r.bearing_temperature_degc = 29.5
    r.viscosity_pa_s = 0.018
    r.static_force_n = [0.0, 5000.0]
    r.load_n = 5000.0
    r.journal_position_m = [5e-5, -8e-5]
    r.sommerfeld_number = 0.6
    r.load_parameter_fy = 0.53
    r.amplitude_d = 0.01
    return [("kcm_solved", m), ("kc_refused_single_tone", r)]


def status_cases():
    m = RigStatus()
    m.header = header(1_700_000_020, 999_999_999)
    m.speed_rad_s = 157.07963267948966
    m.static_load_n = 5603.2
    m.bearing_temperature_degc = 29.003
    m.state = RigStatus.STATE_EXCITING
    m.message = "two-tone 20/30 Hz"
    f = RigStatus()
    f.header = header(-1, 500_000_000)
    f.state = RigStatus.STATE_FAULT
    f.message = "probe_b_y out of its linear range (\u00b1 2 mm)"
    # A TCP stream's DAQ after a flood: every byte of the uint64 count set, after a message
    # that leaves 7 bytes of padding before it.
    d = RigStatus()
    d.header = header(1_700_000_021, 1)
    d.speed_rad_s = 157.07963267948966
    d.static_load_n = 5601.8
    d.bearing_temperature_degc = 28.999
    d.state = RigStatus.STATE_RUNNING
    d.message = "tcp stream of tcp://daq-1:5000#1"
    d.frames_dropped = 0x0102_0304_0506_0708
    return [("exciting", m), ("fault_negative_stamp", f), ("tcp_frames_dropped", d)]


def clock_cases():
    """/clock as our player publishes it: a bag's log time."""
    c = Clock()
    c.clock = Time(sec=1_700_000_000, nanosec=123_456_789)
    z = Clock()
    return [("bag_log_time", c), ("zero", z)]


TYPES = [
    ("ExciterCommand", ExciterCommand, exciter_cases),
    ("DaqFrame", DaqFrame, daq_cases),
    ("ConditionedFrame", ConditionedFrame, conditioned_cases),
    ("CoefficientEstimate", CoefficientEstimate, estimate_cases),
    ("RigStatus", RigStatus, status_cases),
    ("rosgraph_msgs/msg/Clock", Clock, clock_cases),
]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", default=os.path.join(ROOT, "tests", "data", "cdr"))
    ap.add_argument("--check", action="store_true")
    args = ap.parse_args()
    os.makedirs(args.out, exist_ok=True)
    failures = 0
    for full, cls, make in TYPES:
        if "/" not in full:
            full = f"oilfilm_msgs/msg/{full}"
        name = full.rsplit("/", 1)[1]
        cases = []
        for case, msg in make():
            data = serialize_message(msg)
            back = deserialize_message(data, cls)
            if back != msg:
                print(f"FAIL {name}/{case}: deserialize(serialize(m)) != m", file=sys.stderr)
                failures += 1
            if data[:4] != b"\x00\x01\x00\x00":
                print(f"FAIL {name}/{case}: encapsulation header {data[:4].hex()}", file=sys.stderr)
                failures += 1
            cases.append({"name": case, "value": to_plain(msg), "cdr_hex": data.hex()})
            print(f"{name}/{case}: {len(data)} bytes")
        doc = {"type": full, "cases": cases}
        path = os.path.join(args.out, f"{name}.json")
        if args.check:
            with open(path) as f:
                old = json.load(f)
            for a, b in zip(old["cases"], cases):
                if a["value"] != b["value"] or len(a["cdr_hex"]) != len(b["cdr_hex"]):
                    print(f"FAIL {name}/{b['name']}: differs from the committed fixture", file=sys.stderr)
                    failures += 1
            if len(old["cases"]) != len(cases):
                print(f"FAIL {name}: case count differs from the committed fixture", file=sys.stderr)
                failures += 1
        else:
            with open(path, "w") as f:
                json.dump(doc, f, indent=1, ensure_ascii=False)
                f.write("\n")
    if not args.check:
        deps = os.path.join(ROOT, "crates", "msgs", "upstream")
        for pkg, typ in [("std_msgs", "Header"), ("builtin_interfaces", "Time"), ("rosgraph_msgs", "Clock"),
                         ("rcl_interfaces", "ParameterEvent"), ("rcl_interfaces", "Parameter"), ("rcl_interfaces", "ParameterValue")]:
            src = os.path.join(get_package_share_directory(pkg), "msg", f"{typ}.msg")
            dst = os.path.join(deps, pkg, "msg", f"{typ}.msg")
            os.makedirs(os.path.dirname(dst), exist_ok=True)
            with open(src, "rb") as f, open(dst, "wb") as g:
                g.write(f.read())
    if failures:
        print(f"check_msgs: {failures} failure(s)", file=sys.stderr)
        return 1
    print("check_msgs: ok")
    return 0


if __name__ == "__main__":
    sys.exit(main())
