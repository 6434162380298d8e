"""The versions of the libraries a benchmark's figures depend on, printed under its command line: figures are
identical bit for bit only on the same versions (and the same CPU kind). The list is the artifact store's
(``service.store.RUNTIME_PACKAGES``), which keys cached stage outputs by the same versions."""

from __future__ import annotations


def library_versions() -> str:
    """'python 3.11.7, numpy 2.4.6, …' (a package that is not installed is shown as 'missing')."""
    from service.store import runtime_versions

    return ", ".join(f"{k} {v}" for k, v in runtime_versions().items())
