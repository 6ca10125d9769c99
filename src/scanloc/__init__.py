"""scanloc: learned 2D laser localization.

A reproduction of Dietrich (2017) "Deep Learning Localization" with a faithful amcl baseline.
"""

__version__ = "0.1.0"
