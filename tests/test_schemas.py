"""The machine-readable outputs follow their shipped, versioned JSON Schemas."""

from __future__ import annotations

import json

import pytest

from validation.cli.main import main
from validation.schemas import SCHEMAS, SchemaError, load_schema, validate


def _json(capsys, *argv):
    code = main(list(argv))
    out = capsys.readouterr().out
    return code, json.loads(out)


def _also_jsonschema(doc, name):
    """Validate with the ``jsonschema`` package too, where it is installed."""
    try:
        import jsonschema
    except ImportError:
        return
    jsonschema.validate(doc, load_schema(name))


def test_schemas_are_shipped_and_versioned():
    for name in SCHEMAS:
        s = load_schema(name)
        assert s["$schema"].endswith("2020-12/schema") and s["$id"].endswith("/1")
    assert load_schema("run")["properties"]["cipval_results"] == {
        "const": 1,
        "description": "schema version",
    }


def test_the_walker_rejects_what_breaks_a_schema():
    s = load_schema("selftest")
    with pytest.raises(SchemaError, match="missing required 'cipval_selftest'"):
        validate({"pass": True}, s)
    with pytest.raises(SchemaError, match=r"\$\.faults\[0\]\.flagged: expected boolean"):
        doc = {"cipval_selftest": 1, "pass": True, "clean_failures": [], "power": [],
               "faults": [{"fault": "g", "size": 1.0, "unit": "", "flagged": "yes", "by": []}],
               "tolerances": {}, "versions": {}, "platform": "", "fingerprint": {}}  # fmt: skip
        validate(doc, s)


def test_selftest_json_follows_its_schema(selftest_run):
    code, doc, _, _, _ = selftest_run  # `selftest --json`
    assert code == 0
    validate(doc, "selftest")
    _also_jsonschema(doc, "selftest")
    for model in ("single", "coupled"):  # MuJoCo's twin tolerance, set from its floor
        assert doc["tolerances"][f"twin_trajectory_relative_l2.{model}"] == 1e-9
    assert doc["fingerprint"]["versions"] == doc["versions"]


def test_engines_json_follows_its_schema(capsys, tmp_path):
    code, doc = _json(capsys, "engines", "--engines", "reduced", "--profile", "smoke",
                      "--json", "--no-figures", "--out", str(tmp_path))  # fmt: skip
    assert code == 0
    validate(doc, "engines")
    _also_jsonschema(doc, "engines")


def test_sweep_outputs_follow_their_schemas(tmp_path):
    from validation.sweeps import Study, SweepPool, run_sweep

    study = Study(name="schema", model="single", engine="reduced", metrics=("rms",),
                  realizations=2, duration=2.0, seed=1, grid={"beta": [20.0, 21.0]})  # fmt: skip
    run_sweep(study, tmp_path, pool=SweepPool(workers=1))
    validate(json.loads((tmp_path / "study.json").read_text()), "sweep-study")
    points = list((tmp_path / "points").glob("*.json"))
    assert len(points) == 2
    for p in points:
        validate(json.loads(p.read_text()), "sweep-point")
