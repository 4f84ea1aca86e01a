import os

os.environ.setdefault(
    "HAPID_JAX_CACHE", os.path.join(os.path.dirname(__file__), "..", ".hapid_cache", "jax")
)

import hapid  # noqa: E402,F401  (float64 before any test builds arrays)
