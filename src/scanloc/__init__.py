"""scanloc: learned 2D laser localization, a reproduction of Dietrich (2017) "Deep Learning Localization"."""

__version__ = "0.1.0"
