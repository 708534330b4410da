"""The report's paper figures drawn in a child process: ``python -m validation.figure_worker``.

Started with the run (:func:`validation.harness.spawn_figure_worker`), it
imports matplotlib and the figure code while the stages compute, then reads
one line from stdin: the path of a pickle of ``{"out_dir": str, "kwargs":
dict}`` written once the stages the figures draw have finished.  It writes
:func:`validation.plots.paper_figures` into ``out_dir`` and prints their
paths, one a line.  An empty stdin (the run ended first) ends it at once.
"""

from __future__ import annotations

import pickle
import sys
from pathlib import Path


def main() -> int:
    import reduced  # noqa: F401  (classes of the pickled stage results, loaded meanwhile)

    from .plots import paper_figures

    line = sys.stdin.readline().strip()
    if not line:
        return 0
    job = pickle.loads(Path(line).read_bytes())
    for path in paper_figures(Path(job["out_dir"]), **job["kwargs"]):
        print(path)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
