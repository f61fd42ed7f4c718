"""The fit: mean, basis and transfer from the dataset (paper sections 3–5).

Transfer regressors register themselves on import (one line each below).
"""

from prtcore.fit import mlp, ridge  # noqa: F401  (registration)
