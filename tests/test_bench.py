"""The benchmark machinery (tiny run: structure and solution errors, no timing asserts) and the
fast paths it measures against their reference implementations."""

from __future__ import annotations

import argparse
import json

import numpy as np
import pytest
import scipy.linalg as sla

from parallel_gpc import Horizons, ReducedModel, Weights, build_problem, discretize_zoh
from parallel_gpc.gpc import absolute_prediction, condense, incremental_prediction
from parallel_gpc.gpc.settings import stagewise_compiled
from parallel_gpc.model.dynamics import expm
from parallel_gpc.solvers import QRSolver, qr_least_squares
from parallel_gpc.cli.bench import register_bench
from parallel_gpc.bench import BenchConfig, run_benchmark, write_benchmark

from conftest import POSE_A, POSE_B, random_states


# ------------------------------------------------------------------ matrix exponential
@pytest.mark.parametrize("scale", [0.0, 1e-6, 1e-3, 0.05, 0.5, 2.0, 20.0])
def test_fast_expm_matches_scipy_expm(scale):
    rng = np.random.default_rng(int(1e3 * scale) + 1)
    for n in (1, 3, 11):
        M = rng.normal(size=(n, n)) * scale / np.sqrt(n)
        expected = sla.expm(M)
        np.testing.assert_allclose(expm(M), expected, rtol=0, atol=1e-13 * max(1.0, np.abs(expected).max()))


def test_fast_expm_of_a_stack_matches_each_matrix():
    rng = np.random.default_rng(5)
    stack = rng.normal(size=(7, 6, 6)) * np.linspace(1e-4, 1.0, 7)[:, None, None]
    out = expm(stack)
    for M, E in zip(stack, out):
        np.testing.assert_allclose(E, sla.expm(M), rtol=0, atol=1e-14 * max(1.0, np.abs(E).max()))


def test_zoh_of_the_factorized_model_matches_scipy(robot):
    model = ReducedModel(robot)
    X = np.concatenate([0.5 * (POSE_A + POSE_B), [0.4, -0.3, 0.7]])
    A, B, c = model.factorize(X)
    Ts = 0.002
    Ad, Bd, cd = discretize_zoh(A, B, c, Ts)
    n, m = B.shape
    aug = np.zeros((n + m + 1, n + m + 1))
    aug[:n, :n], aug[:n, n:n + m], aug[:n, -1] = A, B, c
    E = sla.expm(aug * Ts)
    np.testing.assert_allclose(Ad, E[:n, :n], rtol=0, atol=1e-14)
    np.testing.assert_allclose(Bd, E[:n, n:n + m], rtol=0, atol=1e-16)
    # the fused path (no intermediate matrices) gives the same numbers
    for got, want in zip(model.discrete(X, Ts), (Ad, Bd, cd)):
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-15)


# ------------------------------------------------------------------ factorization and pre-simulation
def test_coriolis_factor_equals_half_the_velocity_jacobian_of_h_r(robot):
    """A₂₂ = −M_r⁻¹ C_r with C_r = ½ ∂h_r/∂ẏ: check against polarization of h_r (independent)."""
    model = ReducedModel(robot)
    for X in random_states(np.random.default_rng(9), 4):
        A, _, _ = model.factorize(X)
        terms = model.terms(X)
        q, yd = terms.q, X[3:]

        def quad(w):
            return model.terms_at_q(q, w).h_r - model.terms_at_q(q, np.zeros(3)).h_r

        C_r = np.column_stack([0.5 * (quad(yd + e) - quad(yd) - quad(e)) for e in np.eye(3)])
        np.testing.assert_allclose(A[3:, 3:], -np.linalg.solve(terms.M_r, C_r), rtol=1e-9, atol=1e-11)


def test_presimulation_steps_equal_the_discretized_factorization(robot4):
    model, check = ReducedModel(robot4), ReducedModel(robot4)
    X0 = np.concatenate([POSE_A + 0.1, [0.5, 0.3, -0.6]])
    u_seq = np.random.default_rng(2).uniform(-5, 5, (12, 4))
    d = np.array([0, 0, 0, 1e-4, -2e-4, 3e-4])
    A_seq, B_seq, c_seq, Xs = model.simulate_factorized(X0, u_seq, 0.002, d)
    for i in range(len(u_seq)):
        Ad, Bd, cd = discretize_zoh(*check.factorize(Xs[i]), 0.002)
        np.testing.assert_allclose(A_seq[i], Ad, rtol=0, atol=1e-13)
        np.testing.assert_allclose(B_seq[i], Bd, rtol=0, atol=1e-15)
        np.testing.assert_allclose(c_seq[i], cd, rtol=0, atol=1e-15)
        np.testing.assert_allclose(Xs[i + 1], Ad @ Xs[i] + Bd @ u_seq[i] + cd + d, rtol=0, atol=1e-13)


def test_warm_started_assembly_equals_cold_assembly(robot):
    model = ReducedModel(robot)
    for X in random_states(np.random.default_rng(4), 6):
        q = model.assemble(X[:3])
        np.testing.assert_allclose(q, robot.assemble(X[:3]), atol=1e-10)
        assert np.max(np.abs(robot.closure_residual(q))) <= 1e-12


# ------------------------------------------------------------------ condenser and QR paths
@pytest.mark.parametrize("N,No,Nu,hold", [(12, 0, 12, True), (12, 3, 5, True), (12, 2, 4, False), (1, 0, 1, True)])
def test_block_toeplitz_condenser_equals_the_ltv_recursion(N, No, Nu, hold):
    rng = np.random.default_rng(N + No + Nu)
    A = np.eye(5) + 0.1 * rng.normal(size=(5, 5))
    B, c, C, x = rng.normal(size=(5, 3)), rng.normal(size=5), rng.normal(size=(2, 5)), rng.normal(size=5)
    H = Horizons(N, No, Nu)
    f1, G1 = condense(A, B, c, C, x, H, hold)
    # per-step (N, n, n) stacks take the LTV recursion
    f2, G2 = condense(np.broadcast_to(A, (N, 5, 5)), np.broadcast_to(B, (N, 5, 3)),
                      np.broadcast_to(c, (N, 5)), C, x, H, hold)
    np.testing.assert_allclose(f1, f2, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(G1, G2, rtol=1e-12, atol=1e-12)


def test_incremental_step_response_route_equals_the_augmented_model():
    rng = np.random.default_rng(3)
    A = np.eye(4) + 0.1 * rng.normal(size=(4, 4))
    B, c, C, x, u = rng.normal(size=(4, 2)), rng.normal(size=4), rng.normal(size=(2, 4)), rng.normal(size=4), \
        rng.normal(size=2)
    H = Horizons(9, 2, 4)
    fast = incremental_prediction(A, B, c, C, x, u, H)
    slow = incremental_prediction(np.broadcast_to(A, (9, 4, 4)), np.broadcast_to(B, (9, 4, 2)),
                                  np.broadcast_to(c, (9, 4)), C, x, u, H)
    np.testing.assert_allclose(fast.f, slow.f, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(fast.G, slow.G, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("shape", [(40, 12), (12, 40), (20, 20), (140, 80), (60, 80)])
def test_qr_paths_agree(shape):
    rng = np.random.default_rng(sum(shape))
    A, b = rng.normal(size=shape), rng.normal(size=shape[0])
    ref = qr_least_squares(A, b, "pivoted")
    for method in ("lapack", "numpy"):
        v, cost, rank = qr_least_squares(A, b, method)
        assert rank == ref[2]
        np.testing.assert_allclose(v, ref[0], rtol=0, atol=1e-12 * np.abs(ref[0]).max())
        np.testing.assert_allclose(cost, ref[1], rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("qu", [0.0, 1e-3, [1e-3, 0.0, 2e-3, 1e-3]])
@pytest.mark.parametrize("form", ["absolute", "incremental"])
def test_structured_qr_equals_dense_pivoted_qr_on_gpc_problems(model4, form, qu):
    X = np.concatenate([0.5 * (POSE_A + POSE_B), [0.3, -0.2, 0.4]])
    Ad, Bd, cd = model4.discrete(X, 0.002)
    H = Horizons(15)
    pred = (absolute_prediction(Ad, Bd, cd, model4.C, X, H) if form == "absolute"
            else incremental_prediction(Ad, Bd, cd, model4.C, X, np.array([1.0, -2.0, 0.5, 1.5]), H))
    w = np.tile(X[:3] + 1e-3, (15, 1))
    prob = build_problem(pred, w, Weights(1.0, qu), 3, 4)
    fast, ref = QRSolver().solve(prob), QRSolver("pivoted").solve(prob)
    u_fast, u_ref = pred.u_base + pred.u_map @ fast.v, pred.u_base + pred.u_map @ ref.v
    np.testing.assert_allclose(u_fast, u_ref, rtol=0, atol=1e-8 * np.abs(u_ref).max())
    np.testing.assert_allclose(fast.cost, ref.cost, rtol=1e-7, atol=1e-18)


# ------------------------------------------------------------------ the benchmark itself
@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("bench")
    result = run_benchmark(config=BenchConfig.tiny())
    write_benchmark(result, out)
    return result, out


def test_tiny_benchmark_writes_json_and_plot(tiny_run):
    result, out = tiny_run
    data = json.loads((out / "bench_gpc.json").read_text())
    assert set(data) >= {"machine", "config", "limits_Nm", "results", "targets"}
    assert data["machine"]["nproc"] >= 1 and data["machine"]["cpu"]
    assert (out / "bench_gpc.png").stat().st_size > 1000
    sections = {r["section"] for r in data["results"]}
    assert sections == {"unconstrained", "limited", "step", "loop", "qpmpc"}
    for r in data["results"]:
        assert r["samples"] > 0 and r["median_us"] > 0 and r["p99_us"] >= r["median_us"]
        assert r["robot"] == "planar_4rrr" and r["N"] == 10
        assert r["ratio_to_qr"] > 0
    methods = {(r["section"], r["method"]) for r in data["results"]}
    for name in ("qr (LAPACK)", "one LAPACK QR (dgeqrf, same size)", "qr (numpy)", "cholesky (normal eq.)",
                 "daqp-direct"):
        assert ("unconstrained", name) in methods
    for name in ("qr-first:daqp-direct", "bvls", "qr-first:bvls"):  # the controller's default, BVLS
        assert ("limited", name) in methods
    assert ("step", "absolute +limits bvls") in methods
    for r in data["results"]:
        assert r["ratio_to_qr_unit"] > 0
    loops = data["closed_loop"]  # the default (stage-wise at Qu = 1e-5 with the compiled core, else QR), QR, and
    default = "riccati" if stagewise_compiled(False) else "qr"  # the pure-Python reference (QR)
    assert [(loop["solver"], loop.get("reference", False)) for loop in loops] == [
        (default, False), ("qr", False), ("qr", True)]
    assert loops[2]["native"] is False and loops[0]["native"] == loops[1]["native"]
    for loop in loops:
        assert loop["wall_s"] > loop["controller_s"] > 0 and loop["simulated_s"] == BenchConfig.tiny().closed_loop_s
    for form in ("absolute", "incremental", "nonlinear"):
        assert ("step", form) in methods and ("step", f"{form} qr") in methods and ("step", f"{form} +limits") in methods
    names = {t["target"] for t in data["targets"]}
    assert names >= {"absolute step median (replayed)", "nonlinear step median (closed loop)",
                     "absolute step (the default solver) in QR units (replayed)",
                     "nonlinear step (solver qr) in QR units (closed loop)"}
    rows = {(r["section"], r["method"]): r for r in data["results"]}
    for form in ("absolute", "incremental", "nonlinear"):  # the speed-up over the same run's Python step
        fast, ref = rows[("step", form)], rows[("step", f"{form} (Python reference)")]
        assert fast["speedup_over_python"] == pytest.approx(ref["median_us"] / fast["median_us"])
        assert f"{form} step speed-up over the pure-Python reference step (replayed)" in names
    # the default and QR (one target when the default is QR: without the compiled core)
    assert sum(n.startswith("closed loop 0.02 s at 1000 Hz") for n in names) == (2 if default != "qr" else 1)


def test_tiny_benchmark_solutions_match_their_references(tiny_run):
    result, _ = tiny_run
    for r in result["results"]:
        if r["section"] in ("step", "loop"):
            assert r["failures"] == 0, r
            continue
        assert r["failures"] == 0, r
        if r["method"] == "one LAPACK QR (dgeqrf, same size)":  # the unit: a factorization, no solution
            assert r["max_rel_error"] is None
            continue
        if r["method"] == "cholesky (normal eq.)":  # no ridge (unlike the QP back ends): QR accuracy
            assert r["max_rel_error"] < 1e-9, r
        if r["method"] in ("bvls", "qr-first:bvls"):  # exact active set: never costlier than the reference
            assert r["max_rel_cost_gap"] < 1e-10, r
        if r["method"] == "qpmpc:proxqp":  # qpmpc's QP is unscaled: ProxQP stops at ~1e-4
            assert r["max_rel_error"] < 1e-2, r
        elif r["method"].startswith(("qr", "cholesky")) or r["section"] != "unconstrained":
            assert r["max_rel_error"] < 1e-6, r
        else:  # QP back ends carry a 1e-10 relative ridge
            assert r["max_rel_error"] < 1e-6, r
        if r["section"] == "limited":
            assert r["max_violation_Nm"] <= 1e-6, r
    limits = result["limits_Nm"]
    assert len(limits) == 1 and all(v > 0 for v in limits.values())


def test_bench_subcommand_registers():
    parser = argparse.ArgumentParser()
    sub = parser.add_subparsers(dest="command")
    register_bench(sub)
    args = parser.parse_args(["bench", "--quick", "--out", "somewhere"])
    assert args.quick and args.out == "somewhere" and callable(args.func)
