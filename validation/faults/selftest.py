"""``cip-validate selftest``: inject every catalogued fault, show which check flags it.

For each fault of :data:`validation.faults.catalogue.CATALOGUE` the suite's direct checks
(:func:`validation.checks.agreement.instrument_checks`: the full model against its
exact linear twin, the rod's stretch, the delay measured from the engine's
response, the model's declared time step and integrator) run on the faulty
engine with the same seed as the unmodified one.  The selftest passes when the
unmodified model passes every check and every catalogued fault fails at least
one.  ``--power`` also bisects each fault type's size down to the smallest that
is still flagged (a power curve: below it the fault hides in the twin's floor).
The file-level and shared-code paths (:mod:`validation.faults.selftest_paths`) add
their rows and power curves.

Before any of it runs, the command estimates its work (:func:`selftest_work`) and
the memory its recordings take, and refuses, in one line naming ``--realizations``,
beyond :data:`validation.cli.args.MAX_WORK` (unless ``--force``) or the recording cap.
"""

from __future__ import annotations

import argparse
import math
import time

from cipcore.models import MODEL_NAMES, get_model
from cipcore.params import PAPER, ParameterError
from cipcore.scenario import EngineTarget
from validation.checks.agreement import TWIN_WINDOW, instrument_checks, rigid_engine
from validation.checks.stats import FAIL
from validation.cli.args import add_force_arg, add_json_arg, check_work
from validation.cli.ci_options import add_ci_options, junit_file, run_environment
from validation.cli.domains import Domain, add_option
from validation.cli.engine_options import add_engine_options, check_engine_options
from validation.cli.main import add_command, command
from validation.faults.catalogue import (
    CATALOGUE,
    FAULT_TYPES,
    Fault,
    catalogue_sizes,
    make_fault,
)


def flagged_by(
    fault: Fault | None,
    seed: int,
    n_realizations: int,
    engine: str = "mujoco",
    integrator: str | None = None,
) -> list[str]:
    """Names of the checks that fail with ``fault`` injected into ``engine`` (all of them run)."""
    models = fault.models if fault is not None else MODEL_NAMES
    try:
        checks = instrument_checks(seed, n_realizations, threads=1, fault=fault, models=models,
                                   target=EngineTarget(engine, integrator))  # fmt: skip
    except ParameterError as exc:
        if fault is None:
            raise
        # the engine refuses the faulty model (e.g. a bob inertia a point-mass engine
        # cannot represent): the fault cannot pass unnoticed
        return [f"engine refused the model: {exc}"]
    return [c.name for c in checks if c.status == FAIL]


def run_selftest(
    seed: int = 1,
    n_realizations: int = 2,
    kinds: list[str] | None = None,
    engine: str = "mujoco",
    integrator: str | None = None,
) -> tuple[list[str], list[dict]]:
    """(checks failing on the unmodified model, one row per catalogued fault).

    A fault that cannot exist in ``engine`` (a rod softness change in a rigid rod,
    an integrator change in an engine with its own stepper) is listed as not
    applicable with the reason, and is not counted.  The model-file and
    shared-code faults (:mod:`validation.faults.selftest_paths`) follow the catalogue.
    """
    from validation.faults.selftest_paths import clean_failures, path_rows

    eng = rigid_engine(engine)
    clean = flagged_by(None, seed, n_realizations, engine, integrator) + clean_failures(
        seed, n_realizations
    )
    rows = []
    for kind, size, raised in catalogue_sizes(eng.capabilities):
        if kinds and kind not in kinds:
            continue
        fault = make_fault(kind, size)
        row = {"fault": kind, "size": size, "unit": fault.unit, "description": fault.description}
        if raised:
            row["size_note"] = raised
        why = fault.not_applicable(eng)
        if why is not None:
            rows.append({**row, "flagged": None, "by": [], "not_applicable": why, "seconds": 0.0})
            continue
        t = time.perf_counter()
        failed = flagged_by(fault, seed, n_realizations, engine, integrator)
        rows.append({**row, "flagged": bool(failed), "by": failed,
                     "seconds": round(time.perf_counter() - t, 2)})  # fmt: skip
    rows += path_rows(seed, n_realizations, kinds)  # model files as a user's, shared code
    return clean, rows


#: bisection steps of :func:`smallest_detectable` (``--power``)
POWER_ITERATIONS = 12


def smallest_detectable(
    kind: str,
    seed: int,
    n_realizations: int,
    iterations: int = POWER_ITERATIONS,
    engine: str = "mujoco",
    integrator: str | None = None,
) -> dict:
    """Bisection (geometric) on |size| between 1e-12 and the catalogue size (the engine's:
    :func:`validation.faults.catalogue.catalogue_sizes`).

    Fixed faults (flags, sign flips) and one-step delays have no smaller size:
    their row states that.  The sign of the catalogue size is kept.
    """
    spec = FAULT_TYPES[kind]
    caps = rigid_engine(engine).capabilities
    size = {k: s for k, s, _ in catalogue_sizes(caps)}[kind]

    def flagged(fault: Fault, seed: int, n_realizations: int) -> list[str]:
        return flagged_by(fault, seed, n_realizations, engine, integrator)

    if spec.get("fixed") or spec.get("integer"):
        return {"fault": kind, "smallest_flagged": size, "note": "no smaller size exists"}
    identity = spec.get("identity", 0.0)  # the size that means "no fault"
    sign = math.copysign(1.0, size - identity)
    hi, lo = abs(size - identity), 1e-12
    if not flagged(make_fault(kind, identity + sign * hi), seed, n_realizations):
        return {"fault": kind, "smallest_flagged": None, "note": "catalogue size not flagged"}
    if flagged(make_fault(kind, identity + sign * lo), seed, n_realizations):
        unit = make_fault(kind, size).unit
        return {"fault": kind, "smallest_flagged": identity + sign * lo, "deviation": lo,
                "unit": unit, "note": "flagged down to the bisection's floor"}  # fmt: skip
    for _ in range(iterations):
        mid = math.sqrt(hi * lo)
        if flagged(make_fault(kind, identity + sign * mid), seed, n_realizations):
            hi = mid
        else:
            lo = mid
    return {
        "fault": kind,
        "smallest_flagged": identity + sign * hi,
        "largest_missed": identity + sign * lo,
        "deviation": hi,
        "missed_deviation": lo,
        "unit": make_fault(kind, size).unit,
    }


# ------------------------------------------------------------ work estimate
#: the fields each simulation of :func:`validation.checks.agreement.instrument_checks`
#: records (the engine's and its twin's), for the memory check
RECORDED_FIELDS = ("balancing_error", "tip_position")
#: simulations of ``n_realizations`` x ``TWIN_WINDOW`` per model of an instrument_checks
#: call: the engine and its exact twin
SIMULATIONS_PER_MODEL = 2


def model_runs(kinds: list[str] | None, engine: str, power: bool) -> list[tuple[str, str]]:
    """(engine, model) of every model that :func:`instrument_checks` simulates in a selftest.

    One entry per model per :func:`instrument_checks` call of :func:`run_selftest` and
    the power curves: the unmodified model, the equivalent rewrites and the file faults
    (on the default engine, as :mod:`validation.faults.file` runs them), the catalogued
    faults applicable to ``engine`` and, with ``power``, every bisection step of
    :func:`smallest_detectable` (at most 2 + :data:`POWER_ITERATIONS` calls per fault
    with a smaller size).  The
    shared-code faults and the file faults' power curves simulate nothing here (anchors,
    the specification only).  An upper bound: a model whose file fails
    ``model.declared``, or that the engine refuses, is not simulated.
    """
    from validation.faults.file import EQUIVALENT, FILE_CATALOGUE, make_file_fault

    default = EngineTarget().engine
    eng = rigid_engine(engine)
    runs = [(engine, m) for m in MODEL_NAMES]  # the unmodified model
    runs += [(default, m) for _ in EQUIVALENT for m in MODEL_NAMES]
    for kind, size in CATALOGUE:
        if kinds and kind not in kinds:
            continue
        fault = make_fault(kind, size)
        if fault.not_applicable(eng) is not None:
            continue
        runs += [(engine, m) for m in fault.models]
        spec = FAULT_TYPES[kind]
        if power and not (spec.get("fixed") or spec.get("integer")):
            runs += [(engine, m) for m in fault.models] * (2 + POWER_ITERATIONS)
    for kind, size in FILE_CATALOGUE:
        if not kinds or kind in kinds:
            runs += [(default, m) for m in make_file_fault(kind, size).models]
    return runs


def fixed_steps(engine: str, model: str) -> float:
    """Realisation-steps of one model's direct checks that do not scale with the
    realisations: the refinement check (:data:`~validation.checks.refinement.REALIZATIONS`
    force sequences over its window at h, h/2, ..., h / 2**(LEVELS - 1); none for a
    float32 engine its twin judges), for an engine without an exact twin or one that
    declared nothing the closed-loop check (:mod:`validation.checks.closed_loop`, the same
    count), and the delay probe (2 runs of 3 delays, one realisation)."""
    from validation.checks import refinement as rf

    dt = PAPER["dt"]
    caps = rigid_engine(engine).capabilities
    window = rf.precision_setting(model, caps.precision).window
    delay = round(PAPER["tau"] / dt)
    # the open loop, except for a float32 engine its twin judges (FLOAT32_RULE); the closed
    # loop for an engine without a twin or one that declared nothing (its tier is measured)
    twin_tier = caps.twin is not None and caps.declared
    refinements = int(not (twin_tier and caps.precision == "float32")) + int(not twin_tier)
    return refinements * rf.REALIZATIONS * round(window / dt) * (2**rf.LEVELS - 1) + 2 * 3 * delay


def selftest_work(
    n_realizations: int,
    kinds: list[str] | None = None,
    engine: str = "mujoco",
    power: bool = False,
    force: bool = False,
) -> float:
    """The selftest's estimated work (realisation-steps), checked before anything runs.

    ``n_realizations x runs x TWIN_WINDOW / dt + fixed``, where ``runs`` is
    :data:`SIMULATIONS_PER_MODEL` per entry of :func:`model_runs` and ``fixed`` the sum
    of :func:`fixed_steps` over them.  Beyond :data:`validation.cli.args.MAX_WORK`
    (unless ``force``), or when one simulation's recording exceeds its memory cap, a
    :class:`ParameterError` naming ``--realizations``.
    """
    runs = model_runs(kinds, engine, power)
    each = {r: fixed_steps(*r) for r in set(runs)}
    fixed = float(sum(each[r] for r in runs))
    work = check_work("--realizations", n_realizations, TWIN_WINDOW, PAPER["dt"],
                      runs=SIMULATIONS_PER_MODEL * len(runs), fixed=fixed, force=force)  # fmt: skip
    check_recording(n_realizations, list(dict.fromkeys(m for _, m in runs)))
    return work


def check_recording(n_realizations: int, models: list[str]) -> None:
    """Refuse, naming ``--realizations``, a count whose recording (one simulation of
    :data:`RECORDED_FIELDS` over ``TWIN_WINDOW``) exceeds the recording memory cap.

    The model with the most controllers is checked first: the count the message
    offers (at most ...) then holds for every model of ``models``.
    """
    from cipcore.scenario import Recording
    from cipcore.schema import recording_bytes

    rec = Recording(fields=RECORDED_FIELDS)
    n_steps = round(TWIN_WINDOW / PAPER["dt"])  # as instrument_checks counts them
    n_samples = -(-n_steps // rec.decimate)
    for model in sorted(models, key=lambda m: -get_model(m).n_controllers):
        per = recording_bytes(n_steps, 1, get_model(model).n_controllers, rec,
                              len(RECORDED_FIELDS))  # bytes per realisation  # fmt: skip
        if n_realizations * per > rec.max_bytes:
            raise ParameterError(
                f"--realizations: the {model} model's recording {len(RECORDED_FIELDS)} "
                f"field(s) x {n_realizations} realisations x {n_samples} samples needs "
                f"{n_realizations * per / 2**30:.2f} GiB > max_bytes "
                f"{rec.max_bytes / 2**30:.2f} GiB (each of its simulations, "
                f"{TWIN_WINDOW:g} s at dt {PAPER['dt']:g} s); at most "
                f"{rec.max_bytes // per} realisations"
            )


def format_table(clean: list[str], rows: list[dict]) -> str:
    out = ["unmodified model: " + ("pass" if not clean else "FAIL: " + ", ".join(clean)), ""]
    out.append(f"{'fault':<24} {'size':>10} {'unit':<9} {'flagged':<8} by")
    for r in rows:
        by = ", ".join(r["by"]) if r["by"] else "-"
        if r["flagged"] is None:
            flag, by = "n/a", f"not applicable: {r['not_applicable']}"
        else:
            flag = "yes" if r["flagged"] else "NO"
        note = f" (size {r['size_note']})" if r.get("size_note") else ""
        out.append(f"{r['fault']:<24} {r['size']:>10.4g} {r['unit']:<9} "
                   f"{flag:<8} {by}{note}")  # fmt: skip
    return "\n".join(out)


@command(
    "Run the suite's regression checks on the unmodified model and on the model with each "
    "catalogued fault injected (a wrong constant, delay, gain, noise scaling or integrator); the "
    "selftest passes when the unmodified model passes every check and every fault is flagged by "
    "at least one."
)
def cmd_selftest(a: argparse.Namespace) -> int:
    import json

    a.junit = junit_file(a)
    check_engine_options(a)
    kinds = list(a.faults) if a.faults else None  # declared: known faults, each once
    from validation.faults.selftest_paths import path_power

    selftest_work(a.realizations, kinds, a.engine, a.power, a.force)  # before any work
    t = time.perf_counter()
    clean, rows = run_selftest(a.seed, a.realizations, kinds, a.engine, a.integrator)
    rows_run = [r for r in rows if r["flagged"] is not None]
    power = []
    if a.power:
        power = [smallest_detectable(r["fault"], a.seed, a.realizations, engine=a.engine,
                                     integrator=a.integrator)
                 for r in rows_run if "path" not in r]  # fmt: skip
        power += path_power(rows, a.seed, a.realizations)
    ok = not clean and all(r["flagged"] for r in rows_run)
    if a.junit:
        from validation.cli.junit import selftest_cases, write_junit

        write_junit(selftest_cases(clean, rows), a.junit, time.perf_counter() - t)
    if a.json:
        from validation.checks.agreement import TWIN_METRIC_FLOOR
        from validation.report.document import jsonable

        eng = rigid_engine(a.engine)
        tol = {**{f"twin_trajectory_relative_l2.{m}": eng.twin_tolerance_for(m)
                  for m in MODEL_NAMES},
               "twin_metric_floor": TWIN_METRIC_FLOOR,
               "rod_stretch_relative_l2": eng.rod_tolerance}  # fmt: skip
        doc = {"cipval_selftest": 1, "pass": ok, "engine": a.engine, "integrator": a.integrator,
               "clean_failures": clean, "faults": rows, "power": power, "tolerances": tol,
               **run_environment()}  # fmt: skip
        print(json.dumps(jsonable(doc)))
    else:
        print(format_table(clean, rows))
        if power:
            print(
                "\nsmallest flagged deviation from the unmodified model per fault type "
                "(geometric bisection):"
            )
            for p in power:
                if p.get("deviation") is None:
                    print(f"  {p['fault']:<24} {p['smallest_flagged']!s:>10}  {p['note']}")
                    continue
                note = p.get("note") or f"(missed at deviation {p['missed_deviation']:.3g})"
                print(f"  {p['fault']:<24} {p['smallest_flagged']:>10.4g}  deviation "
                      f"{p['deviation']:.3g} {p['unit']} {note}")  # fmt: skip
        print(f"\nselftest of {a.engine} {'passes' if ok else 'FAILS'}: "
              f"{sum(bool(r['flagged']) for r in rows_run)} of {len(rows_run)} applicable "
              f"faults flagged, {time.perf_counter() - t:.1f} s (seed {a.seed}, "
              f"{a.realizations} realisations)")  # fmt: skip
    return 0 if ok else 1


def _fault_names() -> tuple[str, ...]:
    from validation.faults.selftest_paths import PATH_FAULT_TYPES

    return (*FAULT_TYPES, *PATH_FAULT_TYPES)


#: --faults: the catalogue's fault types and the model files' ones (declared here, where
#: the faults are known: :mod:`validation.cli.domains` sits below the fault catalogues)
FAULTS = Domain("faults", "names", choices_of=_fault_names, item="fault")


def register_selftest(sub: argparse._SubParsersAction) -> None:
    """Add ``cip-validate selftest`` to the CLI's subcommands."""
    p = add_command(sub, "selftest", cmd_selftest)
    add_option(p, "--seed", domain="seed", default=1, help="root seed of every noise draw")
    add_option(p, "--realizations", domain="realizations", default=2,
               help="noise realisations per run")  # fmt: skip
    add_option(p, "--faults", domain=FAULTS, metavar="A,B,...",
               help="only these fault types (default: all: "
               + ", ".join(FAULT_TYPES) + ")")  # fmt: skip
    p.add_argument("--power", action="store_true", help="bisect each type's smallest flagged size")
    add_force_arg(p)
    add_json_arg(p)
    add_engine_options(p)
    add_ci_options(p, verbose=False)
