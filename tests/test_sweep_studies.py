"""Research studies: paired model comparisons at target gains, self-describing datasets,
tau_hat with its peak fraction, settings that cannot matter refused."""

from __future__ import annotations

import json

import numpy as np
import pytest
import xarray as xr

from reduced import ParameterError
from validation.sweep import Study, SweepPool, evaluate_point, run_sweep
from validation.sweeps.paired import paired_ci


def compare_study(**kw) -> Study:
    d = {
        "name": "cmp", "engine": "reduced", "compare": ["single", "coupled"],
        "metrics": ("rms", "tau_hat"), "realizations": 6, "duration": 12.0, "seed": 7,
        "common_random_numbers": True, "grid": {"tau": [0.08, 0.12]},
        "gain": {"realizations": 4, "duration": 100.0, "gains": 5, "half_width": 1.0},
        "stcc": {"window": 2.5, "dominance": 0.5},
    }  # fmt: skip
    d.update(kw)
    return Study(**d)


@pytest.fixture(scope="module")
def compared(tmp_path_factory):
    out = tmp_path_factory.mktemp("cmp")
    rep = run_sweep(compare_study(), out, pool=SweepPool(workers=1))
    with xr.open_dataset(rep.dataset_path, engine="scipy") as ds:
        return out, ds.load()


def test_paired_comparison_at_target_gains(compared):
    out, ds = compared
    assert ds["rms"].dims == ("model", "tau", "realization")
    assert list(ds["model"].values) == ["single", "coupled"]
    # beta* per model and delay, inside its interval, coupled above single (Figs. 3, 4)
    b = ds["beta_star"]
    assert (ds["beta_star_ci_low"] <= b).all() and (b <= ds["beta_star_ci_high"]).all()
    assert (b.sel(model="coupled") > b.sel(model="single")).all()
    assert len(list((out / "gains").glob("*.json"))) == 4  # cached: 2 models x 2 delays
    # the ratio is the ratio of medians of the stored realisations, inside its interval
    for tau in (0.08, 0.12):
        s = 10 ** ds["rms"].sel(model="single", tau=tau).values
        c = 10 ** ds["rms"].sel(model="coupled", tau=tau).values
        r = float(ds["rms_ratio_median"].sel(tau=tau))
        assert r == pytest.approx(np.median(c) / np.median(s))
        lo, hi = (float(ds[f"rms_ratio_median_ci_{k}"].sel(tau=tau)) for k in ("low", "high"))
        assert lo <= r <= hi
        g = float(ds["rms_ratio_geomean"].sel(tau=tau))
        assert g == pytest.approx(np.exp(np.mean(np.log(c / s))))
    frac = ds["tau_hat_fraction"].values
    assert np.all((frac >= 0) & (frac <= 1))
    assert ds.attrs["stcc_window"] == 2.5 and ds.attrs["stcc_dominance"] == 0.5


def test_report_has_the_comparison_and_heavy_tail_summaries(compared, tmp_path):
    from validation.sweep import write_sweep_report

    out, _ = compared
    md = write_sweep_report(compare_study(), out).read_text()
    assert "![rms_ratio_median](sweep_rms_ratio_median.png)" in md
    assert "![beta_star](sweep_beta_star.png)" in md
    assert "median RMS (m) [95%]" in md and "mean RMS (m), unstable" in md
    assert (out / "sweep_rms_ratio_median.png").stat().st_size > 0


def test_every_variable_and_coordinate_has_long_name_and_units(compared):
    _, ds = compared
    for name in [*ds.data_vars, *ds.coords]:
        assert ds[name].attrs.get("long_name"), name
        if name != "model":
            assert "units" in ds[name].attrs, name
    for k in ("param_alpha", "param_gamma", "param_nu", "param_dt", "param_amplitude",
              "stcc_max_lag", "stcc_significance_z", "gain_target_lambda1", "seed"):  # fmt: skip
        assert k in ds.attrs, k
    assert "numpy" in json.loads(ds.attrs["versions"])


def test_xarray_plot_labels_axes_with_units(compared):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    _, ds = compared
    ds["rms_ratio_median"].plot()
    ax = plt.gca()
    assert ax.get_xlabel() == "reaction delay tau [s]"
    assert ax.get_ylabel().replace("\n", " ") == "median RMS ratio coupled / single [1]"
    plt.close("all")
    ds["rms"].sel(model="coupled").plot()  # 2-D: a colour map
    ax = plt.gcf().axes
    labels = {t.replace("\n", " ") for a in ax for t in (a.get_xlabel(), a.get_ylabel())}
    assert "log10 of the RMS balancing error [log10(m)]" in labels
    assert "reaction delay tau [s]" in labels
    plt.close("all")


def test_a_point_reruns_from_the_attributes_alone(compared, tmp_path):
    from validation.sweeps.gains import point_gains
    from validation.sweeps.study import point_key

    _, ds = compared
    study = json.loads(ds.attrs["study"])
    point = {"model": "coupled", "tau": 0.12}
    # beta* too: recomputed from the attributes into an empty cache
    gain = point_gains(Study(**study), tmp_path)[point_key(point)]
    for k, v in gain.items():
        assert v == float(ds[k].sel(point)), k
    res = evaluate_point(study, point, 1, gain)
    np.testing.assert_array_equal(res["rms"], ds["rms"].sel(point).values)
    np.testing.assert_array_equal(res["tau_hat_avg"], ds["tau_hat_avg"].sel(point).values)


def test_paired_interval_is_reproducible_and_pairs_realisations():
    rng = np.random.default_rng(1)
    a = rng.normal(0, 1, 40)
    b = a + np.log10(0.5)  # every pair exactly halved: the paired ratio has no spread
    est, lo, hi = paired_ci(a, b, "ratio_geomean", seed=3)
    assert est == pytest.approx(0.5) and lo == pytest.approx(0.5) and hi == pytest.approx(0.5)
    c = b + rng.normal(0, 0.3, 40)
    assert paired_ci(a, c, "ratio_median", 3) == paired_ci(a, c, "ratio_median", 3)


@pytest.mark.parametrize(
    "kw, words",
    [
        ({"engine": "reduced", "grid": {"rod_length": [0.5, 1.0]}},
         ["rod_length", "reduced engine", "no rigid body"]),
        ({"engine": "mujoco", "model": "single", "grid": {"rod_length": [0.5, 1.0]}},
         ["rod_length", "single model", "no rod"]),
        ({"engine": "mujoco", "compare": ["single", "coupled"],
          "grid": {"rod_length_ratio": [0.5]}}, ["rod_length_ratio", "single model"]),
        ({"engine": "reduced", "grid": {"tau": [0.1]}, "fixed": {"beta": 20.0},
          "gain": {"target_lambda1": 5e-4}}, ["beta", "not both"]),
        ({"engine": "reduced", "grid": {"tau": [0.1]}, "stcc": {"lag": 0.3}},
         ["stcc.lag", "allowed"]),
        ({"engine": "reduced", "grid": {"tau": [0.1]}, "compare": ["single"]},
         ["compare", "two"]),
        ({"engine": "reduced", "grid": {"model": ["single", "coupled"]}},
         ["model", "compare"]),
    ],
)  # fmt: skip
def test_settings_that_cannot_matter_are_refused(kw, words):
    d = {"name": "x", "metrics": ("rms",), "realizations": 2, "duration": 2.0, **kw}
    with pytest.raises(ParameterError) as e:
        Study(**d)
    assert "\n" not in str(e.value)
    for w in words:
        assert w in str(e.value)


def test_sweep_export_writes_csv_with_units(compared, tmp_path, capsys):
    import pandas as pd

    from validation.cli.main import main

    out, ds = compared
    assert main(["sweep-export", str(out), "--csv", str(tmp_path / "s.csv")]) == 0
    df = pd.read_csv(tmp_path / "s.csv")
    assert len(df) == ds.sizes["model"] * ds.sizes["tau"] * ds.sizes["realization"]
    assert "rms [log10(m)]" in df.columns and "tau [s]" in df.columns
    assert main(["sweep-export", str(tmp_path / "none"), "--csv", str(tmp_path / "x.csv")]) == 2
    err = capsys.readouterr().err  # a missing directory, not "must name a .nc file"
    assert "cip-validate: error: argument dataset: no such file or directory" in err
