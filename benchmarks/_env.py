"""The versions of the libraries a benchmark's figures depend on, printed under its command line: figures
are identical bit for bit only on the same versions (and the same CPU kind)."""

from __future__ import annotations

import platform
from importlib import metadata

PACKAGES = ("numpy", "scipy", "torch", "opencv-python-headless", "trimesh", "scikit-image", "pybullet")


def library_versions() -> str:
    """'python 3.11.7, numpy 2.4.6, …' (a package that is not installed is shown as 'missing')."""

    def one(p: str) -> str:
        try:
            return f"{p} {metadata.version(p)}"
        except metadata.PackageNotFoundError:
            return f"{p} missing"

    return ", ".join([f"python {platform.python_version()}", *map(one, PACKAGES)])
