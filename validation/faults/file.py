"""Faults in a model *file*, read the way a user's file is: ``cip-validate run --mjcf``.

The engine-level catalogue (:mod:`validation.faults.catalogue`) edits the compiled model
the engine steps while the twin and the controller keep reading the
unmodified file.  A user's file takes another path: the engine, the exact twin
and the mapping all read the same edited file, so the twin follows the fault
and only the specification (:mod:`validation.checks.conformance`) can say that the
file is no longer the paper's system.  Each fault here writes an edited copy
of a shipped MJCF (``models/cip_<model>.xml``, edited as XML with the standard
library's ElementTree) and runs the checks a ``run --mjcf`` runs on it
(``model.conforms`` and the direct checks of
:func:`validation.checks.agreement.instrument_checks`).

:data:`FILE_CATALOGUE` lists the faults the selftest must flag;
:data:`EQUIVALENT` lists rewrites of the shipped files that mean the same
physics (the bob's mass in a welded child body, the pendulum split into two
frames, ``fullinertia``) and must pass.
"""

from __future__ import annotations

import math
import tempfile
import xml.etree.ElementTree as ET
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from cip.mjcf_params import shipped_model_path
from cip.names import ROD, cart_joint, every_balancer, pendulum_body, tip_damper
from cipcore.models import MODEL_NAMES
from cipcore.params import BalanceParams
from cipcore.scenario import EngineTarget
from validation.checks.stats import FAIL

XmlEdit = Callable[[ET.Element], None]


@dataclass(frozen=True)
class FileFault:
    """An edit of a shipped model file (``size`` in the unit of its ``kind``)."""

    kind: str
    size: float
    unit: str
    description: str
    edit: XmlEdit
    models: tuple[str, ...] = MODEL_NAMES

    def write(self, model: str, directory: Path) -> Path:
        """The edited copy of ``models/cip_<model>.xml`` in ``directory``."""
        return write_edited(model, self.edit, directory / f"{self.kind}_{model}.xml")


def write_edited(model: str, edit: XmlEdit, path: Path) -> Path:
    tree = ET.parse(shipped_model_path(model))
    edit(tree.getroot())
    tree.write(path)
    return path


def _floats(text: str) -> list[float]:
    return [float(v) for v in text.split()]


def _fmt(values: list[float]) -> str:
    return " ".join(repr(float(v)) for v in values)


def _pendulums(root: ET.Element) -> list[tuple[ET.Element, ET.Element]]:
    """(body, its ``inertial``) of every pendulum body of the file, listed before any edit."""
    pendulums = every_balancer(pendulum_body)
    return [(b, b.find("inertial")) for b in root.iter("body") if b.get("name", "") in pendulums]


def _pendulum_inertials(root: ET.Element) -> list[ET.Element]:
    return [i for _, i in _pendulums(root)]


def _rod_attr(attr: str, index: int, factor: float | None = None, value: float | None = None):
    def edit(root):
        for eq in root.iter("tendon"):
            if eq.get("name") == ROD and eq.get(attr) is not None:
                v = _floats(eq.get(attr))
                v[index] = v[index] * factor if factor is not None else value
                eq.set(attr, _fmt(v))

    return edit


def _solimp(dmin: float) -> XmlEdit:
    """solimp = (dmin, dmin + (0.99 - dmin)/2, 0.001): a weaker rod impedance."""

    def edit(root):
        for eq in root.iter("tendon"):
            if eq.get("name") == ROD and eq.get("solimp") is not None:
                eq.set("solimp", _fmt([dmin, dmin + (0.99 - dmin) / 2, 0.001]))

    return edit


def _damping(name_of: Callable[[int], str], factor: float) -> XmlEdit:
    def edit(root):
        for g in root.iter("general"):
            if g.get("name", "") in every_balancer(name_of):
                v = _floats(g.get("biasprm"))
                v[2] *= factor
                g.set("biasprm", _fmt(v))

    return edit


def _mass_ratio(factor: float) -> XmlEdit:
    """The bob's mass x factor, its inertia with it (kappa kept), the tip damping's
    biasprm rescaled (gamma kept): m/M x factor and nothing else."""

    def edit(root):
        for i in _pendulum_inertials(root):
            i.set("mass", repr(float(i.get("mass")) * factor))
            i.set("diaginertia", _fmt([v * factor for v in _floats(i.get("diaginertia"))]))
        _damping(tip_damper, factor)(root)

    return edit


def _kappa(kappa: float) -> XmlEdit:
    def edit(root):
        for i in _pendulum_inertials(root):
            m, L = float(i.get("mass")), _floats(i.get("pos"))[2]
            i.set("diaginertia", _fmt([kappa * m * L**2] * 3))

    return edit


def _slide_range(half: float) -> XmlEdit:
    def edit(root):
        for j in root.iter("joint"):
            if j.get("name", "") in every_balancer(cart_joint):
                j.set("range", _fmt([-half, half]))
                j.set("limited", "true")

    return edit


def _gravity(factor: float) -> XmlEdit:
    def edit(root):
        opt = root.find("option")
        g = _floats(opt.get("gravity"))
        opt.set("gravity", _fmt([g[0], g[1], g[2] * factor]))

    return edit


def _f(kind, size, unit, text, edit, models=MODEL_NAMES) -> FileFault:
    return FileFault(kind=kind, size=size, unit=unit, description=text, edit=edit, models=models)


#: How to build any size of each file-fault type (the power curve bisects these).
FILE_FAULT_TYPES: dict[str, dict] = {
    "file_rod_timeconst": {
        "build": lambda s: _f("file_rod_timeconst", s, "factor",
                              "rod solref time constant x s (0.002 s -> 0.002 s x s)",
                              _rod_attr("solref", 0, factor=s), ("coupled",)),
        "identity": 1.0,
    },
    "file_rod_solimp": {
        "build": lambda s: _f("file_rod_solimp", s, "dmin",
                              "rod solimp (s, (s + 0.99)/2, 0.001) instead of (0.99, 0.99, 0.001)",
                              _solimp(s), ("coupled",)),
        "identity": 0.99,
    },
    "file_mass_ratio": {
        "build": lambda s: _f("file_mass_ratio", s, "relative",
                              "bob mass (and inertia) x (1 + s), tip damping rescaled: "
                              "m/M x (1 + s)",
                              _mass_ratio(1 + s)),
    },
    "file_kappa": {
        "build": lambda s: _f("file_kappa", s, "kappa", "bob inertia I = s m L^2", _kappa(s)),
        "identity": 5.03e-9,  # the shipped point bob's
    },
    "file_slide_range": {
        "build": lambda s: _f("file_slide_range", s, "m", "cart slide range +-s",
                              _slide_range(s)),
        "fixed": True,
    },
    "file_gravity": {
        "build": lambda s: _f("file_gravity", s, "relative", "gravity g (1 + s)",
                              _gravity(1 + s)),
    },
    "file_tip_damping": {
        "build": lambda s: _f("file_tip_damping", s, "relative", "tip damping gamma (1 + s)",
                              _damping(tip_damper, 1 + s)),
    },
}  # fmt: skip

#: The file faults the selftest must flag (the sizes a user's file was seen to pass with).
FILE_CATALOGUE: tuple[tuple[str, float], ...] = (
    ("file_rod_timeconst", 50.0),  # solref 0.1
    ("file_rod_timeconst", 250.0),  # solref 0.5
    ("file_rod_solimp", 0.9),
    ("file_mass_ratio", 0.1),
    ("file_kappa", 1e-4),
    ("file_kappa", 1e-2),
    ("file_slide_range", 0.02),
    ("file_gravity", 9.80 / 9.81 - 1.0),  # 9.81 -> 9.80
    ("file_tip_damping", -0.01),
)


def make_file_fault(kind: str, size: float) -> FileFault:
    return FILE_FAULT_TYPES[kind]["build"](size)


# ------------------------------------------------------------ equivalent rewrites
def _explicit_inertia(root: ET.Element) -> None:
    """Masses only where an ``inertial`` says (the shipped files' geoms are visual)."""
    root.find("compiler").set("inertiafromgeom", "false")


def _bob_in_welded_child(root: ET.Element) -> None:
    """The pendulum body keeps the hinge; the bob's mass moves to a child body at the tip."""
    _explicit_inertia(root)
    for b, i in _pendulums(root):
        b.remove(i)
        child = ET.SubElement(b, "body", name="bob_body_" + b.get("name")[-1], pos=i.get("pos"))
        ET.SubElement(child, "inertial", pos="0 0 0", mass=i.get("mass"),
                      diaginertia=i.get("diaginertia"))  # fmt: skip


def _split_frames(root: ET.Element) -> None:
    """The pendulum split in two welded frames at half its length, the bob in the upper."""
    _explicit_inertia(root)
    for b, i in _pendulums(root):
        L = _floats(i.get("pos"))[2]
        b.remove(i)
        site = b.find("site")
        b.remove(site)
        upper = ET.SubElement(b, "body", name="upper_" + b.get("name")[-1], pos=_fmt([0, 0, L / 2]))
        ET.SubElement(upper, "inertial", pos=_fmt([0, 0, L / 2]), mass=i.get("mass"),
                      diaginertia=i.get("diaginertia"))  # fmt: skip
        site.set("pos", _fmt([0, 0, L / 2]))
        upper.append(site)


def _fullinertia(root: ET.Element) -> None:
    """``fullinertia`` (Ixx Iyy Izz Ixy Ixz Iyz) instead of ``diaginertia``."""
    for i in _pendulum_inertials(root):
        d = _floats(i.attrib.pop("diaginertia"))
        i.set("fullinertia", _fmt([*d, 0.0, 0.0, 0.0]))


EQUIVALENT: dict[str, XmlEdit] = {
    "bob_in_welded_child": _bob_in_welded_child,
    "split_frames": _split_frames,
    "fullinertia": _fullinertia,
}


# ------------------------------------------------------------ running them
def file_checks(files: dict[str, str], seed: int, n_realizations: int, models) -> list:
    """The checks ``run --mjcf`` runs on a file without statistics: conformance, direct."""
    from validation.checks.agreement import instrument_checks
    from validation.checks.conformance import conformance_checks

    return conformance_checks(files, tuple(models)) + instrument_checks(
        seed, n_realizations, threads=1, target=EngineTarget(files=files), models=tuple(models)
    )


def flagged_by_file(fault: FileFault, seed: int, n_realizations: int) -> list[str]:
    """Names of the checks that fail on the edited file(s), each with what they name."""
    with tempfile.TemporaryDirectory() as tmp:
        files = {m: str(fault.write(m, Path(tmp))) for m in fault.models}
        checks = file_checks(files, seed, n_realizations, fault.models)
    out = []
    for c in checks:
        if c.status != FAIL:
            continue
        if c.name.startswith("model.conforms"):
            bad = [k for k, v in c.values.items() if not v["ok"]]
            out.append(f"{c.name} ({', '.join(bad)})")
        else:
            out.append(c.name)
    return out


def equivalent_failures(seed: int, n_realizations: int) -> dict[str, list[str]]:
    """For each equivalent rewrite, the checks that fail on it (should be none)."""
    out = {}
    for name, edit in EQUIVALENT.items():
        with tempfile.TemporaryDirectory() as tmp:
            files = {m: str(write_edited(m, edit, Path(tmp) / f"{name}_{m}.xml"))
                     for m in MODEL_NAMES}  # fmt: skip
            checks = file_checks(files, seed, n_realizations, MODEL_NAMES)
        out[name] = [c.name for c in checks if c.status == FAIL]
    return out


def file_rows(seed: int, n_realizations: int, kinds: list[str] | None = None) -> list[dict]:
    """One selftest row per catalogued file fault."""
    import time

    rows = []
    for kind, size in FILE_CATALOGUE:
        if kinds and kind not in kinds:
            continue
        fault = make_file_fault(kind, size)
        t = time.perf_counter()
        by = flagged_by_file(fault, seed, n_realizations)
        rows.append({"path": "file", "fault": kind, "size": size, "unit": fault.unit,
                     "description": fault.description, "flagged": bool(by), "by": by,
                     "seconds": round(time.perf_counter() - t, 2)})  # fmt: skip
    return rows


def flagged_by_conformance(fault: FileFault) -> list[str]:
    """The ``model.conforms`` items an edited file fails (no simulation)."""
    from validation.checks.conformance import conformance_check
    from validation.profiles import PAPER_BETA

    with tempfile.TemporaryDirectory() as tmp:
        checks = [
            conformance_check(m, str(fault.write(m, Path(tmp))), BalanceParams(beta=PAPER_BETA[m]))
            for m in fault.models
        ]
    return [f"{c.name} ({', '.join(k for k, v in c.values.items() if not v['ok'])})"
            for c in checks if c.status == FAIL]  # fmt: skip


def file_power(kind: str, seed: int, n_realizations: int, iterations: int = 10) -> dict:
    """Smallest flagged deviation of a file-fault type from the shipped file (bisection).

    Geometric bisection of |size - identity| between 1e-12 and the catalogued
    size nearest the identity; the sign of the catalogued deviation is kept.
    The bisection asks ``model.conforms`` only: the direct checks follow the
    file's own twin and flag none of these types (the catalogue rows show it,
    except ``model.declared``, which repeats the specification's 1e-12
    equalities of gravity and dampings), so the answer is the same at a
    fraction of the cost; ``seed`` and ``n_realizations`` are kept for the
    selftest's signature.
    """
    spec = FILE_FAULT_TYPES[kind]
    sizes = [s for k, s in FILE_CATALOGUE if k == kind]
    identity = spec.get("identity", 0.0)
    size = min(sizes, key=lambda s: abs(s - identity))
    unit = make_file_fault(kind, size).unit
    if spec.get("fixed"):
        return {"path": "file", "fault": kind, "smallest_flagged": size, "unit": unit,
                "note": "any finite slide range is outside the specification"}  # fmt: skip
    sign = math.copysign(1.0, size - identity)

    def flagged(dev: float) -> bool:
        return bool(flagged_by_conformance(make_file_fault(kind, identity + sign * dev)))

    hi, lo = abs(size - identity), 1e-12
    if not flagged(hi):
        return {"path": "file", "fault": kind, "smallest_flagged": None, "note": "not flagged"}
    if flagged(lo):
        return {"path": "file", "fault": kind, "smallest_flagged": identity + sign * lo,
                "deviation": lo, "unit": unit,
                "note": "flagged down to the bisection's floor"}  # fmt: skip
    for _ in range(iterations):
        mid = math.sqrt(hi * lo)
        if flagged(mid):
            hi = mid
        else:
            lo = mid
    return {"path": "file", "fault": kind, "smallest_flagged": identity + sign * hi,
            "deviation": hi, "missed_deviation": lo, "unit": unit}  # fmt: skip
