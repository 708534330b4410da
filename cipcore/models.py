"""The balancing models as values.

A :class:`BalanceModel` says how many delayed controllers act on one shared
stick-tip coordinate: the paper's single balancer (eq. (3), one
controller) and two balancers whose tips a rigid rod joins (eq. (5), two
controllers, one tip coordinate q_T).  Code asks a model for its number of
controllers or its name; it never compares model names.
"""

from __future__ import annotations

from dataclasses import dataclass

from .params import ParameterError


@dataclass(frozen=True)
class BalanceModel:
    """One balancing model.

    Attributes
    ----------
    name : the name used on the command line and in results.
    n_controllers : C, the number of delayed random-gain controllers (and carts).
    equation : the paper's equation label.
    description : one line for help texts and reports.
    """

    name: str
    n_controllers: int
    equation: str
    description: str

    def __str__(self) -> str:
        return self.name


SINGLE = BalanceModel("single", 1, "(3)", "one balancer (stick on a cart)")
COUPLED = BalanceModel("coupled", 2, "(5)", "two balancers whose stick tips a rigid rod joins")

#: Every model, by name.
MODELS: dict[str, BalanceModel] = {m.name: m for m in (SINGLE, COUPLED)}
MODEL_NAMES: tuple[str, ...] = tuple(MODELS)


def get_model(model: str | BalanceModel) -> BalanceModel:
    """The model called ``model`` (a model passes through); one-line error if unknown."""
    if isinstance(model, BalanceModel):
        return model
    try:
        return MODELS[model]
    except (KeyError, TypeError):
        raise ParameterError(f"model must be one of {', '.join(MODELS)}, got {model!r}") from None
