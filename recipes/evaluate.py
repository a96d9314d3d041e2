"""``python recipes/evaluate.py ...`` runs the ``simdist-evaluate`` console script.

The recipe lives in :mod:`simdist.recipes.evaluate` (installed with the package, so it runs
from any directory); this file keeps the repository path working, as a script and as an
importable module holding the same names.
"""

from simdist.recipes import evaluate as _recipe

if __name__ == "__main__":
    _recipe.main()
else:  # imported by path (tests, benchmarks): expose the recipe's names
    globals().update({k: v for k, v in vars(_recipe).items() if not k.startswith("__")})
