"""The tests' tolerance table: the one in the package (``clholo/tolerances.py``), which
``clholo selftest`` uses too."""

from clholo.tolerances import TOLERANCES, rel_l2, tol  # noqa: F401
