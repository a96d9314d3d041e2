"""``python recipes/twist_dmc.py ...`` runs the ``simdist-twist`` console script.

The recipe lives in :mod:`simdist.recipes.twist_dmc` (installed with the package, so it runs
from any directory); this file keeps the repository path working, as a script and as an
importable module holding the same names.
"""

from simdist.recipes import twist_dmc as _recipe

if __name__ == "__main__":
    _recipe.main()
else:  # imported by path (tests, benchmarks): expose the recipe's names
    globals().update({k: v for k, v in vars(_recipe).items() if not k.startswith("__")})
