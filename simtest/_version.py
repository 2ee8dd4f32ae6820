"""The version of simtest, in one place (``pyproject.toml`` reads it from here).

Kept in a module of its own with no imports so that any module (``simtest.reconstruct.io``,
``simtest.dataset``) can record it without importing the package root.
"""

__version__ = "0.1.0"
