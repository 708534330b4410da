"""CF-style metadata of a sweep dataset: ``long_name`` and ``units`` of every variable and
coordinate, and the settings in force as global attributes.

Units follow UDUNITS spelling where one exists (``s``, ``m``, ``rad``,
``s-1``, ``s-2``, ``1`` for a dimensionless number); a logarithm is written
``log10(m)`` (the decimal logarithm of a length in metres).  xarray labels
plot axes ``long_name [units]`` from these, so
``xarray.open_dataset("sweep.nc").rms.plot()`` needs no extra code.
"""

from __future__ import annotations

from typing import Any

from validation.sweeps.paired import DIFF_METRICS, LOG_METRICS, comparison_names

#: settings (coordinates) -> (long_name, units)
SETTING_ATTRS: dict[str, tuple[str, str]] = {
    "beta": ("gain noise intensity beta", "s-2"),
    "alpha": ("stick stiffness alpha (g / L for a point bob)", "s-2"),
    "gamma": ("mean feedback gain gamma", "s-1"),
    "nu": ("additive noise intensity nu", "s1/2"),
    "tau": ("reaction delay tau", "s"),
    "dt": ("time step", "s"),
    "amplitude": ("initial balancing error", "m"),
    "rod_length": ("rod length l", "m"),
    "rod_length_ratio": ("rod length / pendulum length l/L", "1"),
    "mass_ratio": ("bob / cart mass m/M", "1"),
    "rod_mass": ("rod mass", "kg"),
    "bob_radius": ("bob radius", "m"),
    "solref_timeconst": ("rod constraint time constant", "s"),
    "solref_dampratio": ("rod constraint damping ratio", "1"),
    "solimp_width": ("rod constraint impedance width", "m"),
    "integrator": ("MuJoCo integrator", ""),
    "model": ("balancing model", ""),
    "realization": ("realisation (noise draw) index", "1"),
}

#: data variables -> (long_name, units)
VARIABLE_ATTRS: dict[str, tuple[str, str]] = {
    "seed": ("seed of the point's noise", "1"),
    "diverged": ("a realisation diverged (1) or none (0)", "1"),
    "divergence_time": ("time a realisation diverged (NaN: never)", "s"),
    "lambda1": ("largest Lyapunov exponent lambda1", "s-1"),
    "rms": ("log10 of the RMS balancing error", "log10(m)"),
    "max_angle": ("largest stick angle |theta|", "rad"),
    "agreement": ("relative L2 distance to the reduced model", "1"),
    "tau_hat": ("median first dominant STCC peak tau_hat (windows with a peak)", "s"),
    "tau_hat_fraction": ("fraction of STCC windows with a significant dominant peak", "1"),
    "tau_hat_avg": ("lag of the maximum of the window-averaged STCC", "s"),
    "slope_low": ("low-frequency spectral slope of the balancing error", "1"),
    "slope_high": ("high-frequency spectral slope of the balancing error", "1"),
    "slope_low_se": ("bootstrap SE of the low-frequency slope", "1"),
    "slope_high_se": ("bootstrap SE of the high-frequency slope", "1"),
    "beta_star": ("target gain beta* (reduced model)", "s-2"),
    "beta_star_ci_low": ("beta*, bootstrap 95 % interval, low end", "s-2"),
    "beta_star_ci_high": ("beta*, bootstrap 95 % interval, high end", "s-2"),
}


def variable_attrs(name: str) -> dict[str, str]:
    """``long_name`` and ``units`` of a data variable (paired-comparison names included)."""
    if name in VARIABLE_ATTRS:
        ln, u = VARIABLE_ATTRS[name]
        return {"long_name": ln, "units": u}
    return paired_attrs(name)


def coord_attrs(name: str) -> dict[str, str]:
    ln, u = SETTING_ATTRS.get(name, (name, ""))
    return {"long_name": ln, "units": u} if u else {"long_name": ln}


def label(name: str, attrs: dict[str, Any] | None = None) -> str:
    """``long_name [units]`` of a variable or setting, as xarray writes it."""
    a = attrs or (coord_attrs(name) if name in SETTING_ATTRS else variable_attrs(name))
    ln, u = a.get("long_name", name), a.get("units", "")
    return f"{ln} [{u}]" if u else ln


def paired_attrs(name: str) -> dict[str, str]:
    """``long_name`` / ``units`` of a paired-comparison variable (``{}`` for other names)."""
    bound = ""
    for suffix, text in (("_ci_low", ", 95 % interval low end"),
                         ("_ci_high", ", 95 % interval high end")):  # fmt: skip
        if name.endswith(suffix):
            name, bound = name[: -len(suffix)], text
    for metric in (*LOG_METRICS, *DIFF_METRICS):
        for var, kind in comparison_names(metric):
            if var != name:
                continue
            if kind == "ratio_median":
                return {"long_name": "median RMS ratio compared / reference" + bound,
                        "units": "1"}  # fmt: skip
            if kind == "ratio_geomean":
                return {"long_name": "geometric-mean RMS ratio compared / reference" + bound,
                        "units": "1"}  # fmt: skip
            u = VARIABLE_ATTRS[metric][1]
            return {
                "long_name": f"{metric}: median compared - median reference{bound}",
                "units": u,
            }
    return {}
