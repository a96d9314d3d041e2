"""``python recipes/generate_dataset.py ...`` runs the ``simdist-dataset`` console script from a checkout.

The recipe lives in :mod:`simdist.recipes.generate_dataset` (installed with the package, so it runs
from any directory).
"""

from simdist.recipes import run_from_checkout

run_from_checkout("generate_dataset", __name__, globals())
