"""The paper's claims (sections 3 and 4), one row each, and where each is printed.

* :mod:`~validation.paper.claims`: every claim tested with the reduced models;
* :mod:`~validation.paper.refs`: the paper's equation, figure and table labels.
"""
