"""The paper's printed figure and table numbers for its LaTeX labels.

Yoshida, Higeta, Watanabe (IJICIC 7(3), 2011) numbers its figures in the
order of their captions: the photograph (Fig. 1), the order reduction (2),
lambda1 against beta (3), the balancing errors (4), the spectra (5), the RMS
(6), the velocity densities (7), the STCC at t = 36 (8), the first peak
points (9) and their densities (10), the experimental setup (11), the target
velocities single (12) and coupled (13), the experimental STCCs single (14)
and coupled (15), and the correlation time against the RMS (16).  Its two
tables are the correlation times (Table 1) and the RMS (Table 2) of pair
(A, B).  Its numbered equations: the nonlinear stick (1), its linearisation
(2), the single balancer's target and manipulator (3), the rod's constraint
(4), the coupled model (5) and its relative form (6), lambda1 (7), the STCC
(8).
"""

from __future__ import annotations

import re

#: LaTeX label -> printed figure number
PAPER_FIGURES = {"cip_photo": 1, "1dmodel": 2, "lLe": 3, "Be": 4, "pwsp": 5, "rms": 6,
                 "velo": 7, "scc": 8, "sccpeak": 9, "sccpeak:pdf": 10, "setup": 11,
                 "move_s": 12, "move_c": 13, "stcc_s": 14, "stcc_c": 15, "rmstau": 16}  # fmt: skip
#: LaTeX label -> printed table number
PAPER_TABLES = {"STCC": 1, "RMS": 2}
#: LaTeX label -> printed equation number
PAPER_EQUATIONS = {"cabrera": 1, "bormann04": 2, "bormann04:TM": 3, "dqT": 4, "sss08:TM": 5,
                   "sss08:TMc": 6, "STCC": 8}  # fmt: skip

_FIG = "|".join(re.escape(k) for k in sorted(PAPER_FIGURES, key=len, reverse=True))
_TAB = "|".join(re.escape(k) for k in sorted(PAPER_TABLES, key=len, reverse=True))
_EQ = "|".join(re.escape(k) for k in sorted(PAPER_EQUATIONS, key=len, reverse=True))
_EQ_REF = re.compile(rf"\beq\. \(?({_EQ})\)?(?!\w|:\w)")
_REF = re.compile(rf"\b(?:(Figs?\.) ((?:{_FIG})(?:, (?:{_FIG}))*)|Tab\. ({_TAB}))(?!\w|:\w)")


def printed(text: str) -> str:
    """``text`` with the paper's labels as printed numbers.

    ``"section 3.2, Figs. Be, rms"`` -> ``"section 3.2, Figs. 4, 6"``;
    ``"Tab. STCC"`` -> ``"Table 1"``; ``"eq. (cabrera)"`` -> ``"eq. (1)"``;
    anything else is left as it is.
    """

    def sub(m: re.Match) -> str:
        if m.group(3):
            return f"Table {PAPER_TABLES[m.group(3)]}"
        nums = ", ".join(str(PAPER_FIGURES[k]) for k in m.group(2).split(", "))
        return f"{m.group(1)} {nums}"

    text = _EQ_REF.sub(lambda m: f"eq. ({PAPER_EQUATIONS[m.group(1)]})", text)
    return _REF.sub(sub, text)
