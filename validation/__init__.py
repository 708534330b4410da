"""cipval's validation layer: the checks, their runs, what they write, and the command line.

By role:

* :mod:`validation.run`: ``cip-validate run``, the stages of one validation run;
* :mod:`validation.engines`: every registered engine through those stages, side by side;
* :mod:`validation.profiles`: the run profiles (smoke, quick, full): sizes, gains, seeds;
* :mod:`validation.checks`: what a run measures and the statistics that judge it;
* :mod:`validation.faults`: the fault catalogues and ``selftest``;
* :mod:`validation.report`: results files, the report, figures and clips;
* :mod:`validation.paper`: the paper's claims, one row each;
* :mod:`validation.regression`: baselines and what makes two runs comparable;
* :mod:`validation.sweeps` (public names in :mod:`validation.sweep`): parameter studies;
* :mod:`validation.experiment`: the browser experiment (people in the loop);
* :mod:`validation.exchange`: case files exchanged with other tools;
* :mod:`validation.cli`: the command line, at the edge (nothing else imports its parser
  but the commands that add to it).
"""
