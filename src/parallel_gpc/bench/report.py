"""Benchmark report: the machine, ratios to the QR solve, the targets met or missed, the text
table and the Markdown report of :func:`~parallel_gpc.bench.harness.run_benchmark`'s rows."""

from __future__ import annotations

import os
import platform
from pathlib import Path

#: the targets (s, ratios): full linear step at N = 20 with 4 drives, etc.; the limited step over
#: the unconstrained one, the speed-up over qpmpc and the closed-loop wall time per simulated
#: second at 1 kHz are the "control step near the floor" targets (the limited step's 1.5 is
#: round 3's: "a torque-limited step ≤ 1.5× the unconstrained step of the same form").
TARGETS = {
    "step_median_s": 0.5e-3,
    "step_p99_s": 1.0e-3,
    "limited_over_unconstrained": 1.5,
    "qpmpc_speedup": 8.0,
    "nonlinear_step_median_s": 2.0e-3,
    "closed_loop_wall_per_simulated_s": 0.5,
    "step_speedup_over_python": 4.0,
    "nonlinear_step_speedup_over_python": 6.0,
    "absolute_step_qr_units": 1.3,
    "nonlinear_step_qr_units": 3.0,
}
#: suffix of the step rows timed with the pure-Python model update (the reference of the speed-ups)
PYTHON_REFERENCE = " (Python reference)"
#: the method name of the unit row: one bare LAPACK QR of the stacked problem's size.
QR_UNIT = "one LAPACK QR (dgeqrf, same size)"


# ------------------------------------------------------------------------------- machine
def machine_info() -> dict:
    """CPU, core count and library versions of this machine."""
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    from importlib import metadata

    versions = {}
    for dist in ("numpy", "scipy", "pin", "qpsolvers", "osqp", "proxsuite", "daqp", "qpmpc"):
        try:
            versions[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:  # an optional package is missing: report it
            versions[dist] = None
    try:
        load = [round(x, 2) for x in os.getloadavg()]
    except OSError:  # not available on this platform
        load = None
    return {"cpu": cpu, "nproc": os.cpu_count(), "load_average": load, "python": platform.python_version(),
            "platform": platform.platform(), "OPENBLAS_NUM_THREADS": os.environ.get("OPENBLAS_NUM_THREADS"),
            "versions": versions}


# ------------------------------------------------------------------------------- report
def ratios(rows: list[dict]) -> None:
    """ratio_to_qr: median / median of the QR (LAPACK) solve of the same robot and N;
    ratio_to_qr_unit: median / median of one bare ``dgeqrf`` of the same size (:data:`QR_UNIT`);
    limited steps also get ratio_to_unconstrained_step, and the default steps
    speedup_over_python: the median of the same form's pure-Python reference step (same run,
    same section) over this one."""
    qr = {(r["robot"], r["N"]): r["median_us"] for r in rows
          if r["section"] == "unconstrained" and r["method"] == "qr (LAPACK)"}
    unit = {(r["robot"], r["N"]): r["median_us"] for r in rows
            if r["section"] == "unconstrained" and r["method"] == QR_UNIT}
    steps = {(r["section"], r["robot"], r["N"], r["method"]): r["median_us"] for r in rows
             if r["section"] in ("step", "loop")}
    for r in rows:
        base = qr.get((r["robot"], r["N"]))
        r["ratio_to_qr"] = r["median_us"] / base if base and r["median_us"] else None
        one = unit.get((r["robot"], r["N"]))
        r["ratio_to_qr_unit"] = r["median_us"] / one if one and r["median_us"] else None
        if r["section"] in ("step", "loop") and " +limits" in r["method"]:
            free = steps.get((r["section"], r["robot"], r["N"], r["method"].split(" +limits")[0]))
            r["ratio_to_unconstrained_step"] = r["median_us"] / free if free else None
        if r["section"] in ("step", "loop") and r["median_us"]:
            form = r["method"].removesuffix(" qr")  # the explicit QR rows against their form's reference
            ref = steps.get((r["section"], r["robot"], r["N"], form + PYTHON_REFERENCE))
            r["speedup_over_python"] = ref / r["median_us"] if ref else None


def evaluate_targets(rows: list[dict], closed_loop: list[dict] | None = None, robot: str = "planar_4rrr",
                     N: int = 20) -> list[dict]:
    """The targets at N = 20 on the 4-drive robot (or the nearest measured robot and N), and
    the closed loop's wall time per simulated second: met or missed and by how much."""
    get = {(r["section"], r["robot"], r["N"], r["method"]): r for r in rows}
    robots = sorted({r["robot"] for r in rows})
    if robots and robot not in robots:
        robot = robots[0]
    Ns = sorted({r["N"] for r in rows if r["robot"] == robot})
    if Ns and N not in Ns:
        N = min(Ns, key=lambda n: abs(n - N))
    out = []

    def add(name, value, limit, unit="", better="lower"):
        if value is None:
            return
        ok = value <= limit if better == "lower" else value >= limit
        out.append({"target": name, "robot": robot, "N": N, "value": value, "limit": limit, "unit": unit,
                    "met": bool(ok), "off_by": None if ok else (value / limit if better == "lower" else limit / value)})

    for sec, label in (("step", "replayed"), ("loop", "closed loop")):
        for form in ("absolute", "incremental"):
            r = get.get((sec, robot, N, form))
            if r:
                add(f"{form} step median ({label})", r["median_us"], TARGETS["step_median_s"] * 1e6, "us")
                add(f"{form} step p99 ({label})", r["p99_us"], TARGETS["step_p99_s"] * 1e6, "us")
            for suffix in (" +limits", " +limits daqp-direct", " +limits bvls"):
                lim = get.get((sec, robot, N, f"{form}{suffix}"))
                if lim and lim.get("ratio_to_unconstrained_step"):
                    # the default resolves by gpc.settings.default_solver: at the benchmark's weights and
                    # N ≥ STAGEWISE_LIMITED_MIN_N the stage-wise active set, below it the condensed QP
                    solver = "the default solver" if suffix == " +limits" else suffix[9:]
                    add(f"{form} limited ({solver}) / unconstrained step ({label})",
                        lim["ratio_to_unconstrained_step"], TARGETS["limited_over_unconstrained"], "x")
        r = get.get((sec, robot, N, "nonlinear"))
        if r:
            add(f"nonlinear step median ({label})", r["median_us"], TARGETS["nonlinear_step_median_s"] * 1e6, "us")
        for form in ("absolute", "nonlinear"):  # the default solver's step in units of one LAPACK QR
            for method in (form, f"{form} qr"):
                r = get.get((sec, robot, N, method))
                if r and r.get("ratio_to_qr_unit"):
                    which = "the default solver" if method == form else "solver qr"
                    add(f"{form} step ({which}) in QR units ({label})", r["ratio_to_qr_unit"],
                        TARGETS[f"{form}_step_qr_units"], "QR units")
        for form in ("absolute", "incremental", "nonlinear"):
            goal = TARGETS["nonlinear_step_speedup_over_python" if form == "nonlinear" else "step_speedup_over_python"]
            for method in (form, f"{form} qr"):  # the default (stage-wise) step and the QR one
                r = get.get((sec, robot, N, method))
                if r and r.get("speedup_over_python"):
                    add(f"{method} step speed-up over the pure-Python reference step ({label})",
                        r["speedup_over_python"], goal, "x", better="higher")
    section = [r for k, r in get.items() if k[0] == "qpmpc" and k[1] == robot and k[2] == N and r["median_us"]]
    ours = [r for r in section if r["method"].startswith("ours:")]
    peers = [r for r in section if r["method"].startswith("qpmpc:")]
    if ours and peers:
        best_ours = min(ours, key=lambda r: r["median_us"])
        best_peer = min(peers, key=lambda r: r["median_us"])
        add(f"speed-up over qpmpc ({best_ours['method']} vs {best_peer['method']})",
            best_peer["median_us"] / best_ours["median_us"], TARGETS["qpmpc_speedup"], "x", better="higher")
    for loop in closed_loop or []:
        if loop.get("reference"):  # the pure-Python reference: no target
            continue
        value, limit = loop["wall_per_simulated_s"], TARGETS["closed_loop_wall_per_simulated_s"]
        out.append({"target": f"closed loop {loop['simulated_s']:g} s at {1 / loop['Ts_s']:g} Hz (absolute, "
                              f"{loop['solver']}, N = {loop['N']}, {loop['robot']}): wall s per simulated s",
                    "robot": loop["robot"], "N": loop["N"], "value": value, "limit": limit, "unit": "",
                    "met": value <= limit, "off_by": None if value <= limit else value / limit})
    return out


def format_table(rows: list[dict]) -> str:
    """The results as an aligned text table (µs)."""
    head = (f"{'section':<14}{'robot':<13}{'N':>3}  {'method':<42}{'median':>9}{'p99':>9}{'÷QR':>7}{'÷geqrf':>8}"
            f"  {'error':>8}")
    lines = [head, "-" * len(head)]
    for r in rows:
        ratio, unit = r.get("ratio_to_qr"), r.get("ratio_to_qr_unit")
        err = r.get("max_rel_error")
        extra = ""
        if r.get("ratio_to_unconstrained_step"):
            extra = f"  ({r['ratio_to_unconstrained_step']:.2f}× unconstrained)"
        if r.get("failures"):
            extra += f"  failures {r['failures']}"
        lines.append(
            f"{r['section']:<14}{r['robot']:<13}{r['N']:>3}  {r['method']:<42}"
            f"{_fmt(r['median_us']):>9}{_fmt(r['p99_us']):>9}{(f'{ratio:.2f}' if ratio else '-'):>7}"
            f"{(f'{unit:.2f}' if unit else '-'):>8}  "
            f"{(f'{err:.1e}' if err is not None else '-'):>8}{extra}")
    return "\n".join(lines)


def markdown_report(result: dict) -> str:
    """Markdown: per section, median (p99) in µs for every robot and N, ratio to QR at N = 20 and
    the worst relative solution error; then the targets. (The README's table.)"""
    rows = result["results"]
    robots = list(dict.fromkeys(r["robot"] for r in rows))
    Ns = sorted({r["N"] for r in rows})
    cols = list(dict.fromkeys((r["robot"], r["N"]) for r in rows))  # the (robot, N) pairs measured
    get = {(r["section"], r["method"], r["robot"], r["N"]): r for r in rows}
    titles = {"unconstrained": "Unconstrained solve", "limited": "Solve with torque limits binding at ~half the inputs",
              "step": "Full control step `GPCController.step` (each controller's samples replayed consecutively)",
              "loop": "Full control step in the closed loop (controller and plant alternating)",
              "qpmpc": "LTV MPC problem along the nonlinear pre-simulation: ours vs qpmpc"}
    n_ref = 20 if 20 in Ns else Ns[len(Ns) // 2]
    out = []
    for section in ("unconstrained", "limited", "step", "loop", "qpmpc"):
        methods = list(dict.fromkeys(r["method"] for r in rows if r["section"] == section))
        if not methods:
            continue
        out.append(f"**{titles[section]}** — median (p99) µs")
        out.append("")
        head = "| method | " + " | ".join(f"{rb.replace('planar_', '')} N={n}" for rb, n in cols)
        head += f" | ÷QR ({robots[0].replace('planar_', '')}, N={n_ref}) | ÷dgeqrf | max rel. error |"
        out.append(head)
        out.append("|" + "---|" * (len(cols) + 4))
        for method in methods:
            cells = []
            for rb, n in cols:
                r = get.get((section, method, rb, n))
                cells.append("-" if r is None or r["median_us"] is None else
                             f"{r['median_us']:.0f} ({r['p99_us']:.0f})")
            ref = get.get((section, method, robots[0], n_ref))
            ratio = f"{ref['ratio_to_qr']:.2f}" if ref and ref.get("ratio_to_qr") else "-"
            if ref and ref.get("ratio_to_unconstrained_step"):
                ratio += f" ({ref['ratio_to_unconstrained_step']:.2f}× unconstr.)"
            ratio += f" | {ref['ratio_to_qr_unit']:.2f}" if ref and ref.get("ratio_to_qr_unit") else " | -"
            errs = [get[(section, method, rb, n)]["max_rel_error"] for rb, n in cols
                    if (section, method, rb, n) in get and get[(section, method, rb, n)]["max_rel_error"] is not None]
            fails = sum(get[(section, method, rb, n)]["failures"] for rb, n in cols if (section, method, rb, n) in get)
            err = f"{max(errs):.1e}" if errs else "-"
            if fails:
                err += f" ({fails} failed)"
            out.append(f"| {method} | " + " | ".join(cells) + f" | {ratio} | {err} |")
        out.append("")
    out.append("**Targets** (planar_4rrr, N = 20)")
    out.append("")
    out.append("| target | measured | limit | status |")
    out.append("|---|---|---|---|")
    for t in result["targets"]:
        status = "met" if t["met"] else f"missed ({t['off_by']:.2f}× off)"
        out.append(f"| {t['target']} | {t['value']:.3g} {t['unit']} | {t['limit']:.3g} {t['unit']} | {status} |")
    return "\n".join(out) + "\n"


def _fmt(x) -> str:
    return "-" if x is None else (f"{x:.0f}" if x >= 10 else f"{x:.1f}")


def format_targets(targets: list[dict]) -> str:
    """One line per target of :func:`evaluate_targets`: value, limit, met or missed."""
    lines = []
    for t in targets:
        status = "met" if t["met"] else f"MISSED ({t['off_by']:.2f}× off)"
        lines.append(f"target {t['target']} ({t['robot']}, N = {t['N']}): {t['value']:.3g} {t['unit']} "
                     f"(limit {t['limit']:.3g}) {status}")
    return "\n".join(lines)
