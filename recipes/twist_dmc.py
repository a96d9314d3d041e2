"""``python recipes/twist_dmc.py ...`` runs the ``simdist-twist`` console script from a checkout.

The recipe lives in :mod:`simdist.recipes.twist_dmc` (installed with the package, so it runs
from any directory).
"""

from simdist.recipes import run_from_checkout

run_from_checkout("twist_dmc", __name__, globals())
