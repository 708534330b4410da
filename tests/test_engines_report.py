"""The cross-engine report's second table: what each engine reproduced, read from its checks."""

from __future__ import annotations

from test_engine_contract import assert_tables_well_formed

from validation.engines import markdown, reproduced_table


def _row(engine: str, lam: float, angle: float | None, status: str = "pass") -> dict:
    checks = [
        {"name": f"agreement.lambda1.{m}.beta={b:g}", "status": status,
         "values": {"full": {"value": lam}, "reduced": {"value": -0.011}}}
        for m, b in (("single", 19.5), ("coupled", 20.5))
    ] + [
        {"name": f"agreement.small_angle_regime.{m}", "status": "pass",
         "values": {"largest_agreeing_angle": {"trajectory": angle}}}
        for m in ("single", "coupled")
    ]  # fmt: skip
    caps = {"rigid_body": True, "family": engine, "precision": "float64", "integrator": "Euler"}
    return {"engine": engine, "status": status, "capabilities": caps, "checks": checks,
            "failed": [], "throughput": {"realization_steps_per_s": 1e5, "first_call_s": 0.1,
                                         "wall_s": 0.1, "realizations": 8},
            "trajectory_distance": {"coupled": 2.7e-3}, "seconds": 1.0}  # fmt: skip


def test_each_engine_lists_lambda1_beside_the_reduced_model_and_its_agreeing_angle():
    absent = {"engine": "absent", "status": "skipped", "reason": "not installed"}
    rows = [_row("mujoco", 0.0009, 0.0165), _row("float32", -0.45, None, "fail"), absent]
    res = {"profile": "smoke", "seed": 1, "engines": rows}
    lines = reproduced_table(res)
    header = next(ln for ln in lines if ln.startswith("| engine"))
    assert "lambda1 single, beta 19.5" in header and "lambda1 coupled, beta 20.5" in header
    mujoco = next(ln for ln in lines if ln.startswith("| mujoco"))
    assert "0.001 / -0.011 (pass)" in mujoco and "0.0165" in mujoco
    other = next(ln for ln in lines if ln.startswith("| float32"))
    assert "-0.450 / -0.011 (fail)" in other and other.rstrip(" |").endswith("n/a")
    assert not any(ln.startswith("| absent") for ln in lines)
    md = markdown(res)
    assert "## What each engine reproduced" in md
    assert_tables_well_formed(md)


def test_no_rigid_body_engine_gives_no_table():
    res = {"engines": [{"engine": "absent", "status": "skipped", "reason": "x"}]}
    assert reproduced_table(res) == []
