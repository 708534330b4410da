"""What a run writes for people: results files, the report, its figures and clips.

* :mod:`~validation.report.document`: ``results.json``, ``report.md``, ``report.html``;
* :mod:`~validation.report.captions`: figure captions, stating what each figure shows;
* :mod:`~validation.report.plots`: the figures (matplotlib, imported only to draw);
* :mod:`~validation.report.animation`: the clips of the CIP;
* :mod:`~validation.report.figures`: the worker process that draws figures beside a run.
"""
