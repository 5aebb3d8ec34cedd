"""Settings for the whole suite."""
import os

from hypothesis import HealthCheck, settings

# No per-example time limits and no "too slow" health check (both wall-clock judgements): speed is measured in
# benchmarks/, never asserted in tests, and a loaded CI machine (or a first call that warms a cache) must not turn
# a correct property into a failure.
settings.register_profile("p3at", deadline=None, suppress_health_check=[HealthCheck.too_slow])
# CI (.ci/run sets CI; Hypothesis's own "ci" profile, which this replaces, is the same plus the above): the same
# examples on every run (derandomize: seeded from each test's code), no example database, so a CI run cannot fail
# by the luck of the draw. Local runs ("p3at") draw new examples every time; pin what they find with @example.
settings.register_profile("ci", settings.get_profile("p3at"), derandomize=True, database=None, print_blob=True)
settings.load_profile("ci" if os.environ.get("CI") else "p3at")
