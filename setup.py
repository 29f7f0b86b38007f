"""Packaging beyond what pyproject.toml can say: the shipped track specs live at the top of the
repository (`tracks/`, where people edit them) and install as the package `d2a_tracks`."""

from setuptools import find_packages, setup

setup(
    packages=[*find_packages(include=["d2a_core*", "d2a_cli*"]), "d2a_tracks"],
    package_dir={"d2a_tracks": "tracks"},
)
