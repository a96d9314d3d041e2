"""``python recipes/simdist_quadruped.py ...`` runs the ``simdist-quadruped`` console script.

The recipe lives in :mod:`simdist.recipes.simdist_quadruped` (installed with the package, so it runs
from any directory); this file keeps the repository path working, as a script and as an
importable module holding the same names.
"""

from simdist.recipes import simdist_quadruped as _recipe

if __name__ == "__main__":
    _recipe.main()
else:  # imported by path (tests, benchmarks): expose the recipe's names
    globals().update({k: v for k, v in vars(_recipe).items() if not k.startswith("__")})
