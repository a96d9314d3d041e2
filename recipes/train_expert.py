"""``python recipes/train_expert.py ...`` runs the ``simdist-train-expert`` console script from a checkout.

The recipe lives in :mod:`simdist.recipes.train_expert` (installed with the package, so it runs
from any directory).
"""

from simdist.recipes import run_from_checkout

run_from_checkout("train_expert", __name__, globals())
