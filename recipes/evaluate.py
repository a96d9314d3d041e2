"""``python recipes/evaluate.py ...`` runs the ``simdist-evaluate`` console script from a checkout.

The recipe lives in :mod:`simdist.recipes.evaluate` (installed with the package, so it runs
from any directory).
"""

from simdist.recipes import run_from_checkout

run_from_checkout("evaluate", __name__, globals())
