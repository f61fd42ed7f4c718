"""prtcore: a baker of data-driven Precomputed Radiance Transfer (Belcour et al. 2022).

Pipeline (one module per stage, data flowing one way through frozen dataclasses):
``load`` → ``prepare`` → ``texels`` → ``points`` → ``lights`` → ``transport`` → ``fit``
→ ``bundle`` → ``validate``.
"""

__version__ = "0.1.0"
