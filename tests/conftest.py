"""Settings for the whole suite."""
from hypothesis import settings

# No per-example time limits: speed is measured in benchmarks/, never asserted in tests, and a loaded CI
# machine (or a first call that warms a cache) must not turn a correct property into a failure.
settings.register_profile("p3at", deadline=None)
settings.load_profile("p3at")
