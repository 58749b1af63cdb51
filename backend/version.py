"""The one place the version is written.

The distribution's metadata (``pyproject.toml`` reads it from here), the command line's ``--version``,
the OpenAPI and AsyncAPI ``info.version``, every result and the build-info metric report it. A module of
its own in :mod:`backend`, which the API, the workers and the command line all build on, so that none of
them imports another for it; and a literal only, which setuptools reads without importing the package.
``client/src/eigenscope_client/_version.py`` and the client requirement in ``pyproject.toml`` carry the
same version (``tests/contract/test_packaging.py``).
"""

__version__ = "0.1.0"
