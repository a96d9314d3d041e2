"""``python recipes/simdist_quadruped.py ...`` runs the ``simdist-quadruped`` console script from a checkout.

The recipe lives in :mod:`simdist.recipes.simdist_quadruped` (installed with the package, so it runs
from any directory).
"""

from simdist.recipes import run_from_checkout

run_from_checkout("simdist_quadruped", __name__, globals())
