"""Package list for setuptools (everything else is in pyproject.toml).

``resources/`` sits at the top of the repository (product layout) and is
installed as ``lfm_studio.resources``; ``packages.find`` in pyproject cannot map
a top-level folder into the package, so the list is built here.
"""

from setuptools import find_packages, setup

setup(
    packages=[*find_packages(include=["lfm_studio", "lfm_studio.*"]), "lfm_studio.resources"],
    package_dir={"lfm_studio.resources": "resources"},
)
