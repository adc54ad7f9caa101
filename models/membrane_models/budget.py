"""Memory budgets: what a solution, a kernel or a frame may allocate, checked before it is.

Shared by the exact solutions (``exact``) and the sine-sum kernel (``sines``), which the live
engines use too; a root module so that neither room imports the other for it.
"""

from __future__ import annotations

from membrane_errors import UserError

__all__ = ["MemoryBudgetExceeded", "check_budget"]


class MemoryBudgetExceeded(UserError):
    """A solution, or its frames on a set of points, would need more memory than allowed.

    Raised before the memory is allocated.

    Attributes:
        what: what needs the memory, in words.
        needed: bytes it needs.
        budget: bytes allowed.
    """

    def __init__(self, what: str, needed: int, budget: int) -> None:
        super().__init__(f"{what} needs {needed} bytes, more than the {budget} allowed")
        self.what = what
        self.needed = int(needed)
        self.budget = int(budget)


def check_budget(what: str, needed: int, budget: int | None) -> None:
    """Raise ``MemoryBudgetExceeded`` when ``needed`` bytes exceed ``budget`` (None: no limit)."""
    if budget is not None and needed > budget:
        raise MemoryBudgetExceeded(what, needed, budget)
