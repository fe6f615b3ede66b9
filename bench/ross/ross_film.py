"""ROSS's film coefficients for `oilfilm-bench physics`, timed in this process.

Reads one JSON object from argv[1]: the bearing (diameter_m, length_m, clearance_m,
groove_arc_deg), the grid (n_theta circumferential intervals per pad, n_z intervals over the
half length), the operating point (speed_rpm, load_n downwards, viscosity_pa_s, density_kg_m3)
and repeats. Builds ROSS's PlainJournal (two axial grooves, pads centred on the vertical,
isothermal, the same constant viscosity) on the same grid (total_ex_film = n_theta per pad,
total_ez_film = 2 n_z over the length) and prints one JSON object: ROSS's and Python's
versions, the time of the first solve (which compiles ROSS's kernels) and of each solve
after it (s), the equilibrium and K, C.
"""

import json
import statistics
import sys
import time
import warnings


def main():
    p = json.loads(sys.argv[1])
    warnings.filterwarnings("ignore")
    import numpy as np
    import ross
    from ross.bearings.plain_journal import PlainJournal
    from ross.units import Q_

    mu = p["viscosity_pa_s"]
    oil = {
        "liquid_viscosity1": mu,
        "temperature1": 300.0,
        "liquid_viscosity2": mu,
        "temperature2": 350.0,
        "liquid_density": p["density_kg_m3"],
        "liquid_specific_heat": 1950.0,
        "liquid_thermal_conductivity": 0.13,
        "vapour_viscosity": 9e-06,
        "vapour_density": 0.029,
        "vapour_specific_heat": 1000.0,
        "vapour_thermal_conductivity": 0.026,
        "saturation_pressure": 1e5,
        "surface_tension": 0.04,
        "molecular_weight": 0.5,
    }

    def solve():
        return PlainJournal(
            n=0,
            pad_axial_length=p["length_m"],
            journal_diameter=p["diameter_m"],
            radial_clearance=p["clearance_m"],
            n_pads=2,
            pad_arc=Q_(180.0 - p["groove_arc_deg"], "deg"),
            preload=0.0,
            oil_supply_temperature=300.0,
            speed=Q_([p["speed_rpm"]], "RPM"),
            fxs_load=0.0,
            fys_load=-p["load_n"],
            lubricant=oil,
            oil_flow_v=1e-2,
            thermal_type=None,
            total_ex_film=p["n_theta"],
            total_ez_film=2 * p["n_z"],
        )

    t0 = time.perf_counter()
    bearing = solve()  # the first solve compiles ROSS's numba kernels: timed apart
    warmup = time.perf_counter() - t0
    times = []
    for _ in range(max(1, p["repeats"])):
        t0 = time.perf_counter()
        bearing = solve()
        times.append(time.perf_counter() - t0)
    w = p["speed_rpm"] * 2.0 * np.pi / 60.0
    k = np.asarray(bearing.K(w), dtype=float)
    c = np.asarray(bearing.C(w), dtype=float)
    print(json.dumps({
        "ross": ross.__version__,
        "python": sys.version.split()[0],
        "median_s": statistics.median(times),
        "warmup_s": warmup,
        "seconds": times,
        "eccentricity": float(bearing.equilibrium_pos[0]),
        "attitude_deg": float(np.degrees(bearing.equilibrium_pos[1])),
        "stiffness_n_m": k.tolist(),
        "damping_n_s_m": c.tolist(),
    }))


if __name__ == "__main__":
    main()
