#!/usr/bin/env python3
"""SciPy RK45 peer of `host-sim simulate`: the nominal plant of shared/plant/PLANT.md replayed
open loop on the valve inputs of a recording (zero-order hold, one solve_ivp segment per
sample), written as a RECORDING.md CSV. Used only to measure the speed of host-sim against a
typical SciPy implementation (docs/reliability.md):

    python3 scripts/rk45_peer.py ../shared/plant/reference-1dof.toml \
        ../shared/conformance/pulses_nominal.csv /tmp/peer.csv

Tolerances rtol = 1e-6, atol = 1e-6 (host-sim's simulate default is tighter).
"""
import csv
import math
import sys
import time

try:
    import tomllib
except ImportError:  # Python < 3.11
    import tomli as tomllib

import numpy as np
from scipy.integrate import solve_ivp


def main(plant_path, rec_path, out_path):
    t0 = time.perf_counter()
    with open(plant_path, "rb") as f:
        cfg = tomllib.load(f)
    env, mus, jnt, vlv, ini = (cfg[k] for k in ("environment", "muscle", "joint", "valve", "initial"))
    p_atm = env["p_atm_pa"]
    p_s = env["supply_gauge_pa"] + p_atm
    l_n, r0 = mus["rest_length_m"], mus["radius_m"]
    alpha0 = math.radians(mus["braid_angle_deg"])
    k, gamma = mus["end_factor"], mus["damping_m2s"]
    b0, b1, b2, b3 = mus["volume_poly_m3"]
    r, J, chi0 = jnt["sprocket_radius_m"], jnt["inertia_kgm2"], jnt["initial_contraction"]
    C, bc, ll = vlv["sonic_conductance_m3_per_s_pa"], vlv["critical_ratio"], vlv["laminar_ratio"]
    a_t = 3.0 / math.tan(alpha0) ** 2
    b_t = 1.0 / math.sin(alpha0) ** 2

    def phi(s):
        if s <= bc:
            return 1.0
        if s < ll:
            return math.sqrt(1.0 - ((s - bc) / (1.0 - bc)) ** 2)
        phi_l = math.sqrt(1.0 - ((ll - bc) / (1.0 - bc)) ** 2)
        return phi_l * (1.0 - s) / (1.0 - ll)

    def q(p_up, p_dn):
        if p_up < p_dn:
            return -q(p_dn, p_up)
        return C * p_up * phi(p_dn / p_up)

    def tension(chi, dchi, pg):
        fs = max(0.0, math.pi * r0 * r0 * pg * (a_t * (1.0 - k * chi) ** 2 - b_t))
        return max(0.0, fs - gamma * pg * dchi)

    def rhs(_t, x, u):
        beta, omega, p1, p2 = x
        chi1 = chi0 + r / l_n * beta
        chi2 = chi0 - r / l_n * beta
        dchi1 = r / l_n * omega
        dchi2 = -dchi1
        f1 = tension(chi1, dchi1, p1 - p_atm)
        f2 = tension(chi2, dchi2, p2 - p_atm)
        out = [omega, (f1 - f2) * r / J]
        for chi, dchi, p, uin, uex in ((chi1, dchi1, p1, u[0], u[1]), (chi2, dchi2, p2, u[2], u[3])):
            v = b0 + b1 * chi + b2 * chi * chi + b3 * chi ** 3
            dv = (b1 + 2 * b2 * chi + 3 * b3 * chi * chi) * dchi
            qi = uin * q(p_s, p) - uex * q(p, p_atm)
            out.append((p_atm * qi - p * dv) / v)
        return out

    t, u = [], []
    meta = []
    with open(rec_path) as f:
        lines = [l for l in f]
    body = [l for l in lines if not l.lstrip().startswith("#") and l.strip()]
    rd = csv.DictReader(body)
    for row in rd:
        t.append(float(row["t_s"]))
        u.append([float(row[c]) for c in ("u_in1", "u_ex1", "u_in2", "u_ex2")])
    n = len(t)
    dt = t[1] - t[0]
    x = np.array([ini["angle_rad"], ini["velocity_rad_s"], ini["p1_gauge_pa"] + p_atm, ini["p2_gauge_pa"] + p_atm])
    states = np.empty((n, 4))
    first_step = None
    for i in range(n):
        states[i] = x
        if i + 1 < n:
            sol = solve_ivp(rhs, (t[i], t[i + 1]), x, method="RK45", rtol=1e-6, atol=1e-6, args=(u[i],))
            x = sol.y[:, -1]
    with open(out_path, "w", newline="") as f:
        f.write(f"# plant = {plant_path}\n# sample_period_s = {dt}\n# source = scripts/rk45_peer.py scipy RK45\n")
        w = csv.writer(f)
        w.writerow(["t_s", "u_in1", "u_ex1", "u_in2", "u_ex2", "angle_deg", "p1_kpa", "p2_kpa", "f1_n", "f2_n"])
        for i in range(n):
            beta, omega, p1, p2 = states[i]
            chi1 = chi0 + r / l_n * beta
            chi2 = chi0 - r / l_n * beta
            dchi1 = r / l_n * omega
            f1 = tension(chi1, dchi1, p1 - p_atm)
            f2 = tension(chi2, -dchi1, p2 - p_atm)
            w.writerow([f"{t[i]:.6f}", *u[i], f"{math.degrees(beta):.6f}", f"{(p1 - p_atm) / 1e3:.6f}",
                        f"{(p2 - p_atm) / 1e3:.6f}", f"{f1:.6f}", f"{f2:.6f}"])
    print(f"{out_path}: {n} samples in {time.perf_counter() - t0:.2f} s", file=sys.stderr)


if __name__ == "__main__":
    main(*sys.argv[1:4])
