"""Where the data shipped with the package lives: the MJCF scene and the model archive.

In a checkout (and an editable install) they are the repository's `assets/` and `archive/`,
beside the package; a wheel (`pip install .`) carries copies inside the package. One lookup
for both, so nothing else needs to know how the package was installed.
"""

from __future__ import annotations

from pathlib import Path

PACKAGE_DIR = Path(__file__).resolve().parent


def shipped(name: str) -> Path:
    """The shipped folder `name` ("assets" or "archive"): inside the package when a wheel
    carries it, else beside the package (a checkout)."""
    inside = PACKAGE_DIR / name
    return inside if inside.is_dir() else PACKAGE_DIR.parent / name
