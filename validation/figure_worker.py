"""The report's paper figures drawn in a child process: ``python -m validation.figure_worker JOB``.

``JOB`` is a pickle of ``{"out_dir": str, "kwargs": dict}`` written by
:func:`validation.harness.start_paper_figures` once the stages the figures
draw have finished; the child writes :func:`validation.plots.paper_figures`
into ``out_dir`` and prints their paths, one a line, while the run computes
its remaining stages.
"""

from __future__ import annotations

import pickle
import sys
from pathlib import Path


def main(argv: list[str] | None = None) -> int:
    job = pickle.loads(Path((sys.argv[1:] if argv is None else argv)[0]).read_bytes())
    from .plots import paper_figures

    for path in paper_figures(Path(job["out_dir"]), **job["kwargs"]):
        print(path)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
